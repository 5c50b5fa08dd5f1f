//! Adam (Kingma & Ba 2015) with its moments held as tensors, so a checkpoint can carry them and a
//! resumed run continues exactly where it stopped (tch's built-in optimiser keeps its state opaque).

use tch::{Device, Kind, Tensor};

/// Makes `params` views of one contiguous buffer (their values kept) and returns that buffer, so
/// one elementwise kernel updates them all: an update at the thesis sizes runs ~25 small tensors
/// per network, and per-tensor dispatch, not arithmetic, is what the optimiser step costs.
pub fn flatten_parameters(params: &[Tensor]) -> Tensor {
    let flat = tch::no_grad(|| {
        let pieces: Vec<Tensor> = params.iter().map(|p| p.detach().reshape([-1])).collect();
        Tensor::cat(&pieces, 0)
    });
    for (p, view) in params.iter().zip(views_like(&flat, params)) {
        p.shallow_clone().set_data(&view);
    }
    flat
}

/// Views of `flat` shaped like `params` (the per-parameter layout of a flat buffer).
fn views_like(flat: &Tensor, params: &[Tensor]) -> Vec<Tensor> {
    let mut offset = 0;
    params
        .iter()
        .map(|p| {
            let n = p.numel() as i64;
            let view = flat.narrow(0, offset, n).view(p.size().as_slice());
            offset += n;
            view
        })
        .collect()
}

/// Zero for a subnormal x, x otherwise. A first moment whose gradient is exactly zero (a dead
/// ReLU unit) decays by beta1 a step into the subnormal range and sticks there (a tenth of the
/// smallest subnormal rounds to zero), where x86 takes a microcode assist of some hundred cycles
/// on every operation that reads or writes it: 24,000 such moments in a critic made its Adam
/// pass 4 times slower. Flushed, they are zero, which moves no parameter by a representable
/// amount either (and a normal value passes unchanged, so the arithmetic is otherwise the same).
#[inline(always)]
fn flush_subnormal(x: f32) -> f32 {
    if x.abs() < f32::MIN_POSITIVE {
        0.0
    } else {
        x
    }
}

/// One step's scalars, in f32 as the buffers are.
struct StepCoefficients {
    /// 1 - beta1 and 1 - beta2, formed in f64: 1 - 0.999f32 would be 4.7e-5 off.
    one_minus_beta1: f32,
    one_minus_beta2: f32,
    /// learning rate / (1 - beta1^t)
    step_size: f32,
    /// 1 / sqrt(1 - beta2^t)
    inverse_sqrt_bias2: f32,
    epsilon: f32,
}

impl StepCoefficients {
    /// Adam on slices: m <- lerp(m, g, 1 - b1), v <- lerp(v, g^2, 1 - b2),
    /// p <- p - step m / (sqrt(v) / sqrt(bias2) + eps) (PyTorch's placement of eps).
    /// Every element's arithmetic is the same at any vector width (no fused multiply-add is
    /// formed), so the widest one the CPU has is taken at run time: the result is bit-for-bit
    /// the same, and the pass, 14 % of an SAC update at SSE width, takes 6.5 % at AVX-512
    /// (perf, one thread); it is then bound by memory.
    fn apply(&self, params: &mut [f32], m: &mut [f32], v: &mut [f32], g: &[f32]) {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has AVX-512F, checked just above.
                return unsafe { self.apply_avx512(params, m, v, g) };
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU has AVX2, checked just above.
                return unsafe { self.apply_avx2(params, m, v, g) };
            }
        }
        self.apply_portable(params, m, v, g);
    }

    #[inline(always)]
    fn apply_portable(&self, params: &mut [f32], m: &mut [f32], v: &mut [f32], g: &[f32]) {
        let (a1, a2) = (self.one_minus_beta1, self.one_minus_beta2);
        for (((p, m), v), &g) in params.iter_mut().zip(m.iter_mut()).zip(v.iter_mut()).zip(g) {
            *m = flush_subnormal(*m + a1 * (g - *m));
            *v = flush_subnormal(*v + a2 * (g * g - *v));
            *p -= self.step_size * *m / (v.sqrt() * self.inverse_sqrt_bias2 + self.epsilon);
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn apply_avx512(&self, params: &mut [f32], m: &mut [f32], v: &mut [f32], g: &[f32]) {
        self.apply_portable(params, m, v, g);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn apply_avx2(&self, params: &mut [f32], m: &mut [f32], v: &mut [f32], g: &[f32]) {
        self.apply_portable(params, m, v, g);
    }
}

/// Why [`Adam::load_state`] refused a checkpoint's optimiser state.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AdamStateError {
    /// The state lacks this tensor (`PREFIX.m.i`, `PREFIX.v.i` or `PREFIX.steps`).
    #[error("missing tensor {0}")]
    Missing(String),
    /// A moment tensor's shape differs from its parameter's (another network size).
    #[error("tensor {name} has shape {found:?}, expected {expected:?}")]
    Shape {
        /// The tensor's name.
        name: String,
        /// Its shape in the checkpoint.
        found: Vec<i64>,
        /// The shape of the parameter it belongs to.
        expected: Vec<i64>,
    },
}

/// Adam over a fixed list of parameters (the trainable tensors of one network), which it makes
/// views of one flat buffer ([`flatten_parameters`]); moments are flat too.
pub struct Adam {
    params: Vec<Tensor>,
    flat_params: Tensor,
    first_moment: Tensor,
    second_moment: Tensor,
    steps: i64,
    /// One fused pass on the CPU; tensor kernels elsewhere (CUDA).
    fused: bool,
    /// Step size (PyTorch's `lr`), read at every step.
    pub learning_rate: f64,
    beta1: f64,
    beta2: f64,
    epsilon: f64,
}

impl Adam {
    /// PyTorch's defaults apart from the learning rate: beta = (0.9, 0.999), epsilon = 1e-8.
    pub fn new(params: Vec<Tensor>, learning_rate: f64) -> Self {
        let flat_params = flatten_parameters(&params);
        let zeros = || flat_params.zeros_like().set_requires_grad(false);
        Self {
            first_moment: zeros(),
            second_moment: zeros(),
            params,
            fused: flat_params.device() == Device::Cpu,
            flat_params,
            steps: 0,
            learning_rate,
            beta1: 0.9,
            beta2: 0.999,
            epsilon: 1e-8,
        }
    }

    /// The parameters, in the order [`Adam::step`] takes their gradients.
    pub fn parameters(&self) -> &[Tensor] {
        &self.params
    }

    /// The parameters' shared buffer (for Polyak averaging of a whole network at once).
    pub fn flat_parameters(&self) -> &Tensor {
        &self.flat_params
    }

    /// Back-propagates `loss` to this optimiser's parameters and takes one Adam step. The
    /// gradients are returned by the autograd engine, not accumulated into the parameters'
    /// `.grad` (PyTorch's `zero_grad(set_to_none=True)`): no pass zeroes them, none adds into
    /// them, and no other network's weight gradients are formed.
    pub fn backward_step(&mut self, loss: &Tensor) {
        let grads = Tensor::run_backward(&[loss], &self.params, false, false);
        self.step(&grads);
    }

    /// One update from the gradients `grads`, one per parameter in order (an undefined one
    /// counts as a zero gradient: its moments decay).
    pub fn step(&mut self, grads: &[Tensor]) {
        self.steps += 1;
        let bias1 = 1.0 - self.beta1.powi(self.steps as i32);
        let bias2 = 1.0 - self.beta2.powi(self.steps as i32);
        let coefficients = StepCoefficients {
            one_minus_beta1: (1.0 - self.beta1) as f32,
            one_minus_beta2: (1.0 - self.beta2) as f32,
            step_size: (self.learning_rate / bias1) as f32,
            inverse_sqrt_bias2: (1.0 / bias2.sqrt()) as f32,
            epsilon: self.epsilon as f32,
        };
        tch::no_grad(|| {
            if self.fused {
                self.fused_cpu_step(grads, &coefficients);
            } else {
                self.tensor_step(grads, &coefficients);
            }
        });
    }

    /// The update as tensor kernels (any device; a GPU's arithmetic takes subnormals at full
    /// speed, so they are not flushed here).
    fn tensor_step(&mut self, grads: &[Tensor], c: &StepCoefficients) {
        let grads: Vec<Tensor> = self
            .params
            .iter()
            .zip(grads)
            .map(|(p, g)| {
                if g.defined() {
                    g.reshape([-1])
                } else {
                    p.zeros_like().reshape([-1])
                }
            })
            .collect();
        let g = Tensor::cat(&grads, 0);
        let _ = self.first_moment.lerp_(&g, f64::from(c.one_minus_beta1));
        // v <- beta2 v + (1 - beta2) g^2 is a lerp towards g^2.
        let _ = self.second_moment.lerp_(&g.square(), f64::from(c.one_minus_beta2));
        // p <- p - step m / (sqrt(v / bias2) + eps), the sign and scale folded into the
        // denominator.
        let step = f64::from(c.step_size);
        let mut denom = self.second_moment.sqrt();
        let _ = denom.g_mul_scalar_(-f64::from(c.inverse_sqrt_bias2) / step);
        let _ = denom.g_add_scalar_(-f64::from(c.epsilon) / step);
        let _ = self.flat_params.addcdiv_(&self.first_moment, &denom);
    }

    /// The update as one pass over each parameter's gradient and its slices of the flat
    /// parameter and moment buffers. As tensor kernels it is six passes over ~4 MB at the thesis
    /// sizes (perf: 15 % of an update on one thread); fused, one.
    fn fused_cpu_step(&mut self, grads: &[Tensor], c: &StepCoefficients) {
        let grads: Vec<Tensor> = self
            .params
            .iter()
            .zip(grads)
            .map(|(p, g)| {
                if !g.defined() {
                    p.zeros_like()
                } else if g.kind() == Kind::Float && g.is_contiguous() {
                    // As it comes from the backward passes: no conversion to dispatch.
                    g.shallow_clone()
                } else {
                    g.to_kind(Kind::Float).contiguous()
                }
            })
            .collect();
        // Check the whole layout before touching memory, so a mismatch (impossible for buffers
        // built by `new`) falls back to the tensor kernels without a half-applied step.
        let sizes: Vec<usize> = self.params.iter().map(Tensor::numel).collect();
        let fits = sizes.iter().sum::<usize>() == self.flat_params.numel()
            && grads.iter().zip(&sizes).all(|(g, &n)| g.numel() == n);
        if !fits {
            return self.tensor_step(&grads, c);
        }
        let mut offset = 0usize;
        for (g, n) in grads.iter().zip(sizes) {
            // SAFETY: the three flat buffers are contiguous f32 CPU tensors created by `new` and
            // owned by this optimiser, and [offset, offset + n) lies inside them (the sizes sum
            // to their length, checked above); `g` is a contiguous f32 CPU tensor of n elements
            // that outlives the slices. Nothing else reads or writes these buffers during the
            // step (no_grad, one thread, `&mut self`), and the four regions do not overlap
            // (distinct allocations).
            let (params, m, v, g) = unsafe {
                (
                    std::slice::from_raw_parts_mut((self.flat_params.data_ptr() as *mut f32).add(offset), n),
                    std::slice::from_raw_parts_mut((self.first_moment.data_ptr() as *mut f32).add(offset), n),
                    std::slice::from_raw_parts_mut((self.second_moment.data_ptr() as *mut f32).add(offset), n),
                    std::slice::from_raw_parts(g.data_ptr() as *const f32, n),
                )
            };
            c.apply(params, m, v, g);
            offset += n;
        }
    }

    /// Named state for a checkpoint: moments per parameter plus the step count.
    pub fn state(&self, prefix: &str) -> Vec<(String, Tensor)> {
        let m = views_like(&self.first_moment, &self.params);
        let v = views_like(&self.second_moment, &self.params);
        let mut out = Vec::with_capacity(2 * self.params.len() + 1);
        for (i, (m, v)) in m.into_iter().zip(v).enumerate() {
            out.push((format!("{prefix}.m.{i}"), m));
            out.push((format!("{prefix}.v.{i}"), v));
        }
        out.push((format!("{prefix}.steps"), Tensor::from_slice(&[self.steps])));
        out
    }

    /// Restores the state written by [`Adam::state`]; shapes must match.
    pub fn load_state(&mut self, prefix: &str, get: &dyn Fn(&str) -> Option<Tensor>) -> Result<(), AdamStateError> {
        let m = views_like(&self.first_moment, &self.params);
        let v = views_like(&self.second_moment, &self.params);
        for (i, (m, v)) in m.into_iter().zip(v).enumerate() {
            for (name, mut dst) in [(format!("{prefix}.m.{i}"), m), (format!("{prefix}.v.{i}"), v)] {
                let Some(src) = get(&name) else {
                    return Err(AdamStateError::Missing(name));
                };
                if src.size() != dst.size() {
                    return Err(AdamStateError::Shape {
                        name,
                        found: src.size(),
                        expected: dst.size(),
                    });
                }
                tch::no_grad(|| dst.copy_(&src.to_kind(Kind::Float)));
            }
        }
        let steps_name = format!("{prefix}.steps");
        let steps = get(&steps_name).ok_or(AdamStateError::Missing(steps_name))?;
        self.steps = steps.int64_value(&[0]);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::nn::{self, Module, VarStore};
    use tch::Device;

    /// Adam written out per scalar in f64 (Kingma & Ba, Algorithm 1 with PyTorch's placement of
    /// epsilon), the reference the flat tensor implementation must follow.
    fn reference_adam(params: &mut [f64], m: &mut [f64], v: &mut [f64], grads: &[f64], step: i32, lr: f64) {
        let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-8);
        for i in 0..params.len() {
            m[i] = b1 * m[i] + (1.0 - b1) * grads[i];
            v[i] = b2 * v[i] + (1.0 - b2) * grads[i] * grads[i];
            let m_hat = m[i] / (1.0 - b1.powi(step));
            let v_hat = v[i] / (1.0 - b2.powi(step));
            params[i] -= lr * m_hat / (v_hat.sqrt() + eps);
        }
    }

    fn values(tensors: &[Tensor]) -> Vec<f64> {
        tensors
            .iter()
            .flat_map(|t| Vec::<f32>::try_from(t.reshape([-1])).unwrap_or_default())
            .map(f64::from)
            .collect()
    }

    /// A two-layer network trained through the store's own modules: the flattened parameters
    /// stay the modules' parameters, and every step equals the scalar reference on the same
    /// gradients; the checkpoint views read the flat moments back per parameter.
    #[test]
    fn flat_adam_follows_the_scalar_reference_through_the_modules() {
        for fused in [true, false] {
            follows_the_scalar_reference(fused);
        }
    }

    /// A gradient that stops (a unit gone dead) leaves its first moment decaying by beta1 a
    /// step: the fused pass takes it to exactly zero, never into the subnormal range, where
    /// unflushed f32 arithmetic would leave it stuck at the smallest subnormal for good.
    #[test]
    fn a_moment_whose_gradient_stops_decays_to_zero_not_to_a_subnormal() {
        let param = Tensor::from_slice(&[0.5f32, -0.25, 1.0, 2.0]);
        let mut adam = Adam::new(vec![param.shallow_clone()], 1e-3);
        assert!(adam.fused);
        adam.step(&[Tensor::from_slice(&[1e-3f32, -2e-3, 5e-4, 1.0])]);
        let zero = Tensor::zeros([4], (Kind::Float, Device::Cpu));
        let first_moment = |adam: &Adam| Vec::<f32>::try_from(&adam.first_moment).unwrap_or_default();
        let mut seen_below_normal = false;
        for _ in 0..1_000 {
            adam.step(&[zero.shallow_clone()]);
            let m = first_moment(&adam);
            seen_below_normal |= m.iter().any(|x| *x != 0.0 && x.abs() < 1e-37);
            assert!(m.iter().all(|x| !x.is_subnormal()), "{m:?}");
        }
        assert_eq!(first_moment(&adam), vec![0.0; 4]);
        // The moments did pass through the smallest normal values on the way (0.9^k from 1e-4).
        assert!(seen_below_normal);
        let v = Vec::<f32>::try_from(&adam.second_moment).unwrap_or_default();
        assert!(v.iter().all(|x| !x.is_subnormal() && *x > 0.0), "{v:?}");
    }

    fn follows_the_scalar_reference(fused: bool) {
        tch::manual_seed(3);
        let store = VarStore::new(Device::Cpu);
        let net = nn::seq()
            .add(nn::linear(store.root() / "a", 3, 4, Default::default()))
            .add_fn(|x| x.tanh())
            .add(nn::linear(store.root() / "b", 4, 2, Default::default()));
        let params = store.trainable_variables();
        let mut reference = values(&params);
        let (mut m, mut v) = (vec![0.0; reference.len()], vec![0.0; reference.len()]);
        let lr = 0.05;
        let mut adam = Adam::new(params.iter().map(Tensor::shallow_clone).collect(), lr);
        adam.fused = fused;
        assert_eq!(values(&params), reference, "flattening keeps the values");
        let x = Tensor::from_slice(&[0.5f32, -1.0, 2.0, 0.1, 0.3, -0.4]).view([2, 3]);
        let mut params = params;
        for step in 1..=5 {
            // The reference's gradients by autograd's accumulating path, taken before the step.
            for p in &mut params {
                p.zero_grad();
            }
            net.forward(&x).square().sum(Kind::Float).backward();
            let grads = values(&params.iter().map(|p| p.grad()).collect::<Vec<_>>());
            adam.backward_step(&net.forward(&x).square().sum(Kind::Float));
            reference_adam(&mut reference, &mut m, &mut v, &grads, step, lr);
            for (got, want) in values(&params).iter().zip(&reference) {
                assert!(
                    (got - want).abs() <= 1e-6 * (1.0 + want.abs()),
                    "fused {fused}, step {step}: {got} vs {want}"
                );
            }
        }
        // The store's variables (what the modules read) live inside the optimiser's buffer.
        let flat = adam.flat_parameters();
        let (start, bytes) = (flat.data_ptr() as usize, flat.numel() * 4);
        for (name, t) in store.variables() {
            let at = t.data_ptr() as usize;
            assert!(
                at >= start && at + t.numel() * 4 <= start + bytes,
                "{name} outside the buffer"
            );
        }
        let state = adam.state("adam");
        let moments: Vec<Tensor> = (0..params.len()).map(|i| state[2 * i].1.shallow_clone()).collect();
        for (got, want) in values(&moments).iter().zip(&m) {
            assert!((got - want).abs() <= 1e-6 * (1.0 + want.abs()));
        }
        assert_eq!(
            state.last().map(|(n, t)| (n.as_str(), t.int64_value(&[0]))),
            Some(("adam.steps", 5))
        );
    }
}
