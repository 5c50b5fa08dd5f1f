//! Adam (Kingma & Ba 2015) with its moments held as tensors, so a checkpoint can carry them and a
//! resumed run continues exactly where it stopped (tch's built-in optimiser keeps its state opaque).

use tch::{Kind, Tensor};

/// Adam over a fixed list of parameters (the trainable tensors of one network).
pub struct Adam {
    params: Vec<Tensor>,
    first_moment: Vec<Tensor>,
    second_moment: Vec<Tensor>,
    steps: i64,
    pub learning_rate: f64,
    beta1: f64,
    beta2: f64,
    epsilon: f64,
}

impl Adam {
    /// PyTorch's defaults apart from the learning rate: beta = (0.9, 0.999), epsilon = 1e-8.
    pub fn new(params: Vec<Tensor>, learning_rate: f64) -> Self {
        let zeros = |p: &Tensor| p.zeros_like().set_requires_grad(false);
        let first_moment = params.iter().map(zeros).collect();
        let second_moment = params.iter().map(zeros).collect();
        Self {
            params,
            first_moment,
            second_moment,
            steps: 0,
            learning_rate,
            beta1: 0.9,
            beta2: 0.999,
            epsilon: 1e-8,
        }
    }

    /// Clears the gradients, back-propagates `loss` and takes one Adam step.
    pub fn backward_step(&mut self, loss: &Tensor) {
        for p in &mut self.params {
            p.zero_grad();
        }
        loss.backward();
        self.step();
    }

    /// One update from the gradients currently stored on the parameters.
    pub fn step(&mut self) {
        self.steps += 1;
        let bias1 = 1.0 - self.beta1.powi(self.steps as i32);
        let bias2 = 1.0 - self.beta2.powi(self.steps as i32);
        let step_size = self.learning_rate / bias1;
        tch::no_grad(|| {
            for ((p, m), v) in self
                .params
                .iter_mut()
                .zip(&mut self.first_moment)
                .zip(&mut self.second_moment)
            {
                let g = p.grad();
                if !g.defined() {
                    continue;
                }
                let _ = m.lerp_(&g, 1.0 - self.beta1);
                let _ = v.g_mul_scalar_(self.beta2);
                let _ = v.addcmul_(&(&g * (1.0 - self.beta2)), &g);
                let denom = (v.sqrt() / bias2.sqrt()) + self.epsilon;
                let _ = p.addcdiv_(&(&*m * -step_size), &denom);
            }
        });
    }

    /// Named state for a checkpoint: moments per parameter plus the step count.
    pub fn state(&self, prefix: &str) -> Vec<(String, Tensor)> {
        let mut out = Vec::with_capacity(2 * self.params.len() + 1);
        for (i, (m, v)) in self.first_moment.iter().zip(&self.second_moment).enumerate() {
            out.push((format!("{prefix}.m.{i}"), m.shallow_clone()));
            out.push((format!("{prefix}.v.{i}"), v.shallow_clone()));
        }
        out.push((format!("{prefix}.steps"), Tensor::from_slice(&[self.steps])));
        out
    }

    /// Restores the state written by [`Adam::state`]; shapes must match.
    pub fn load_state(&mut self, prefix: &str, get: &dyn Fn(&str) -> Option<Tensor>) -> Result<(), String> {
        for (i, (m, v)) in self.first_moment.iter_mut().zip(&mut self.second_moment).enumerate() {
            for (name, dst) in [(format!("{prefix}.m.{i}"), m), (format!("{prefix}.v.{i}"), v)] {
                let src = get(&name).ok_or_else(|| format!("missing tensor {name}"))?;
                if src.size() != dst.size() {
                    return Err(format!(
                        "tensor {name} has shape {:?}, expected {:?}",
                        src.size(),
                        dst.size()
                    ));
                }
                tch::no_grad(|| dst.copy_(&src.to_kind(Kind::Float)));
            }
        }
        let steps = get(&format!("{prefix}.steps")).ok_or_else(|| format!("missing tensor {prefix}.steps"))?;
        self.steps = steps.int64_value(&[0]);
        Ok(())
    }
}
