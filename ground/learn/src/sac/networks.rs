//! The actor (squashed Gaussian) and critic networks. Layer names are fixed because the exporter
//! reads them: `l0`, `l1`, ... for hidden layers, `mean` and `log_std` for the actor's heads, `q`
//! for the critic's output. Weights are tch's [out, in].

use tch::nn::{self, Module};
use tch::{Kind, Tensor};

/// Bounds on the actor's log standard deviation (Haarnoja et al.'s reference code).
pub const LOG_STD_MIN: f64 = -20.0;
/// The upper bound (the lower is [`LOG_STD_MIN`]).
pub const LOG_STD_MAX: f64 = 2.0;

fn hidden_layers(path: &nn::Path, input: usize, hidden: &[usize], init: nn::LinearConfig) -> Vec<nn::Linear> {
    let mut widths = vec![input as i64];
    widths.extend(hidden.iter().map(|&h| h as i64));
    widths
        .windows(2)
        .enumerate()
        .map(|(i, w)| nn::linear(path / format!("l{i}"), w[0], w[1], init))
        .collect()
}

/// pi(a|s): a = tanh(u), u ~ N(mean(s), std(s)^2).
pub struct Actor {
    trunk: Vec<nn::Linear>,
    mean: nn::Linear,
    log_std: nn::Linear,
}

/// An action drawn from the actor with its log-density (after the tanh squash).
pub struct ActionSample {
    /// The squashed action tanh(u), [batch, act_dim], in (-1, 1).
    pub action: Tensor,
    /// log pi(a|s) of the squashed action, summed over its components, [batch, 1].
    pub log_prob: Tensor,
    /// The Gaussian's mean (before the squash).
    mean: Tensor,
}

impl ActionSample {
    /// tanh(mean): the deterministic action flown onboard (formed only where it is used: the
    /// target's sample never needs it).
    pub fn mean_action(&self) -> Tensor {
        self.mean.tanh()
    }
}

impl Actor {
    /// A freshly initialised actor under `path` (PyTorch's `nn.Linear` initialisation, from the torch
    /// generator): ReLU hidden layers of widths `hidden`, then `mean` and `log_std` heads of `act_dim`.
    pub fn new(path: &nn::Path, obs_dim: usize, act_dim: usize, hidden: &[usize]) -> Self {
        Self::with_init(path, obs_dim, act_dim, hidden, Default::default())
    }

    /// An actor whose weights start at zero, for copies that are overwritten at once (the
    /// averaged actor): it draws nothing from the random generator, so switching such a copy
    /// on leaves every other network's initial weights and samples unchanged.
    pub fn zeroed(path: &nn::Path, obs_dim: usize, act_dim: usize, hidden: &[usize]) -> Self {
        let zero = nn::LinearConfig {
            ws_init: nn::Init::Const(0.0),
            bs_init: Some(nn::Init::Const(0.0)),
            bias: true,
        };
        Self::with_init(path, obs_dim, act_dim, hidden, zero)
    }

    fn with_init(path: &nn::Path, obs_dim: usize, act_dim: usize, hidden: &[usize], init: nn::LinearConfig) -> Self {
        let last = *hidden.last().unwrap_or(&obs_dim) as i64;
        Self {
            trunk: hidden_layers(path, obs_dim, hidden, init),
            mean: nn::linear(path / "mean", last, act_dim as i64, init),
            log_std: nn::linear(path / "log_std", last, act_dim as i64, init),
        }
    }

    /// Each hidden layer's input, then the heads' input.
    fn trunk_inputs(&self, obs: &Tensor) -> Vec<Tensor> {
        let mut inputs = vec![obs.shallow_clone()];
        for layer in &self.trunk {
            let h = layer.forward(&inputs[inputs.len() - 1]).relu_();
            inputs.push(h);
        }
        inputs
    }

    /// The deterministic action tanh(mean(s)).
    pub fn deterministic(&self, obs: &Tensor) -> Tensor {
        let inputs = self.trunk_inputs(obs);
        self.mean.forward(&inputs[inputs.len() - 1]).tanh()
    }

    /// A reparameterised sample (gradients flow through mean and std).
    pub fn sample(&self, obs: &Tensor) -> ActionSample {
        self.sample_recorded(obs).0
    }

    /// The sample and the spread std * noise it added to the mean.
    fn squash(mean: Tensor, log_std: Tensor) -> (ActionSample, Tensor) {
        let noise = mean.randn_like();
        let spread = log_std.exp() * &noise;
        let pre_tanh = &mean + &spread;
        let log_prob = squashed_gaussian_log_prob(&pre_tanh, &noise, &log_std);
        let sample = ActionSample {
            action: pre_tanh.tanh(),
            log_prob,
            mean,
        };
        (sample, spread)
    }

    /// The trainable tensors in the order [`Actor::backward`] returns their gradients.
    pub fn parameters(&self) -> Vec<Tensor> {
        let mut params = Vec::new();
        for layer in self.trunk.iter().chain([&self.mean, &self.log_std]) {
            params.push(layer.ws.shallow_clone());
            params.extend(layer.bs.as_ref().map(Tensor::shallow_clone));
        }
        params
    }

    /// A sample with what the hand-written backward pass needs: every layer's input (the ReLU
    /// outputs double as their masks) and the unclamped log-standard deviation.
    pub fn sample_recorded(&self, obs: &Tensor) -> (ActionSample, ActorPass) {
        let inputs = self.trunk_inputs(obs);
        let h = &inputs[inputs.len() - 1];
        let mean = self.mean.forward(h);
        let raw_log_std = self.log_std.forward(h);
        let log_std = raw_log_std.clamp(LOG_STD_MIN, LOG_STD_MAX);
        let (sample, spread) = Self::squash(mean, log_std.shallow_clone());
        (
            sample,
            ActorPass {
                inputs,
                raw_log_std,
                log_std,
                spread,
            },
        )
    }

    /// Gradients of a loss with respect to [`Actor::parameters`], in that order, from its
    /// gradients with respect to the mean and the clamped log-standard deviation of a recorded
    /// pass: the chain rule written out layer by layer (a linear layer y = x W^T + b gives
    /// dW = g^T x, db = sum g, dx = g W; a ReLU passes g where its output is positive; the clamp
    /// passes it inside its bounds), as autograd would form it, without recording a graph.
    pub fn backward(&self, pass: &ActorPass, grad_mean: &Tensor, grad_log_std: &Tensor) -> Vec<Tensor> {
        let grad_raw_log_std = grad_log_std * pass.log_std.eq_tensor(&pass.raw_log_std);
        let h = &pass.inputs[pass.inputs.len() - 1];
        let mut head_grads = Vec::new();
        for (layer, g) in [(&self.mean, grad_mean), (&self.log_std, &grad_raw_log_std)] {
            head_grads.push(g.tr().mm(h));
            if layer.bs.is_some() {
                head_grads.push(g.sum_dim_intlist(0, false, Kind::Float));
            }
        }
        let mut g = grad_mean.mm(&self.mean.ws).addmm(&grad_raw_log_std, &self.log_std.ws);
        let mut trunk_grads = Vec::new();
        for (l, layer) in self.trunk.iter().enumerate().rev() {
            g = pass.inputs[l + 1].threshold_backward(&g, 0.0);
            if layer.bs.is_some() {
                trunk_grads.push(g.sum_dim_intlist(0, false, Kind::Float));
            }
            trunk_grads.push(g.tr().mm(&pass.inputs[l]));
            if l > 0 {
                g = g.mm(&layer.ws);
            }
        }
        trunk_grads.reverse();
        trunk_grads.extend(head_grads);
        trunk_grads
    }
}

/// What [`Actor::backward`] needs of a forward pass.
pub struct ActorPass {
    /// The input of each hidden layer, then the heads' input.
    inputs: Vec<Tensor>,
    raw_log_std: Tensor,
    log_std: Tensor,
    /// std * noise of the sample.
    spread: Tensor,
}

/// The gradients with respect to the mean and the clamped log-standard deviation of a recorded
/// sample, from those with respect to its action ([batch, act_dim]) and its log-density (a
/// scalar, the same for every row). With u = mean + std noise (noise held fixed) and
/// log pi = sum_j (-noise_j^2 / 2 - log_std_j - log(2 pi) / 2 - log(1 - tanh(u_j)^2)):
/// d(log pi)/du_j = 2 tanh(u_j) and d(log pi)/d(log_std_j) = -1 besides the path through u.
pub fn squashed_sample_gradients(
    sample: &ActionSample,
    pass: &ActorPass,
    grad_action: &Tensor,
    grad_log_prob: &Tensor,
) -> (Tensor, Tensor) {
    let a = &sample.action;
    let grad_pre_tanh = grad_action * (1.0 - a.square()) + a * (grad_log_prob * 2.0);
    let grad_log_std = &grad_pre_tanh * &pass.spread - grad_log_prob;
    (grad_pre_tanh, grad_log_std)
}

/// log pi(tanh(u)) for u = mean + std * noise, summed over action dimensions, shape [batch, 1].
/// The change of variables subtracts log(1 - tanh(u)^2), written as 2 (log 2 - u - softplus(-2u))
/// so it stays finite where tanh saturates (the naive form needs an epsilon and is biased there).
pub fn squashed_gaussian_log_prob(pre_tanh: &Tensor, noise: &Tensor, log_std: &Tensor) -> Tensor {
    let gaussian = (noise.square() * -0.5) - log_std - 0.5 * (2.0 * std::f64::consts::PI).ln();
    let log_det = (std::f64::consts::LN_2 - pre_tanh - (pre_tanh * -2.0).softplus()) * 2.0;
    (gaussian - log_det).sum_dim_intlist(-1, true, tch::Kind::Float)
}

/// SAC's two critics Q1(s, a), Q2(s, a) evaluated together: layer l stores both networks'
/// weights stacked as `w{l}` [2, in, out] and biases `b{l}` [2, 1, out], so each layer is one
/// batched matrix product for both (half the kernel calls of two separate networks, the same
/// arithmetic). The two networks stay independent: separate initial draws, no shared weight.
pub struct TwinCritic {
    weights: Vec<Tensor>,
    biases: Vec<Tensor>,
}

impl TwinCritic {
    /// Both critics freshly initialised under `path` (PyTorch's `nn.Linear` initialisation, separate
    /// draws): input (s, a) concatenated, ReLU hidden layers of widths `hidden`, one Q output.
    pub fn new(path: &nn::Path, obs_dim: usize, act_dim: usize, hidden: &[usize]) -> Self {
        let mut widths = vec![(obs_dim + act_dim) as i64];
        widths.extend(hidden.iter().map(|&h| h as i64));
        widths.push(1);
        let (mut weights, mut biases) = (Vec::new(), Vec::new());
        for (l, w) in widths.windows(2).enumerate() {
            // PyTorch's nn.Linear default: U(-1/sqrt(in), 1/sqrt(in)) for weights and biases.
            let bound = 1.0 / (w[0] as f64).sqrt();
            let init = nn::Init::Uniform { lo: -bound, up: bound };
            weights.push(path.var(&format!("w{l}"), &[2, w[0], w[1]], init));
            biases.push(path.var(&format!("b{l}"), &[2, 1, w[1]], init));
        }
        Self { weights, biases }
    }

    /// Both Q values, shape [2, batch, 1].
    pub fn forward(&self, obs: &Tensor, action: &Tensor) -> Tensor {
        self.forward_recorded(obs, action).q
    }

    /// min(Q1, Q2), shape [batch, 1].
    pub fn min_q(&self, obs: &Tensor, action: &Tensor) -> Tensor {
        self.forward(obs, action).amin(0, false)
    }

    /// The trainable tensors in the order [`TwinCritic::weight_gradients`] returns theirs.
    pub fn parameters(&self) -> Vec<Tensor> {
        self.weights
            .iter()
            .zip(&self.biases)
            .flat_map(|(w, b)| [w.shallow_clone(), b.shallow_clone()])
            .collect()
    }

    /// Both Q values with every layer's input (the ReLU outputs double as their masks), for the
    /// hand-written backward passes.
    pub fn forward_recorded(&self, obs: &Tensor, action: &Tensor) -> CriticPass {
        let mut inputs = vec![Tensor::cat(&[obs, action], 1).unsqueeze(0).expand([2, -1, -1], false)];
        let last = self.weights.len() - 1;
        let mut q = Tensor::new();
        for (l, (w, b)) in self.weights.iter().zip(&self.biases).enumerate() {
            let mut h = b.baddbmm(&inputs[l], w, 1.0, 1.0);
            if l < last {
                inputs.push(h.relu_());
            } else {
                q = h;
            }
        }
        CriticPass {
            inputs,
            q,
            action_width: action.size()[1],
        }
    }

    /// Gradients of a loss with respect to [`TwinCritic::parameters`], in that order, from its
    /// gradient with respect to both Q values of a recorded pass ([2, batch, 1]): the chain rule
    /// written out (a layer y = b + x W gives dW = x^T g, db = sum g, dx = g W^T per network;
    /// a ReLU passes g where its output is positive), as autograd would form it.
    pub fn weight_gradients(&self, pass: &CriticPass, grad_q: &Tensor) -> Vec<Tensor> {
        let mut grads = Vec::with_capacity(2 * self.weights.len());
        let mut g = grad_q.shallow_clone();
        for l in (0..self.weights.len()).rev() {
            if l + 1 < self.weights.len() {
                g = pass.inputs[l + 1].threshold_backward(&g, 0.0);
            }
            grads.push(g.sum_dim_intlist(1, true, Kind::Float));
            grads.push(pass.inputs[l].transpose(1, 2).bmm(&g));
            if l > 0 {
                g = g.bmm(&self.weights[l].transpose(1, 2));
            }
        }
        grads.reverse();
        grads
    }

    /// d min(Q1, Q2) / da row by row ([batch, act_dim]) of a recorded pass, `chosen` (`[batch]`,
    /// 0 or 1) naming the critic that min picked in each row, where min's gradient goes. The
    /// rows are grouped by that critic and each group goes back through its own critic alone,
    /// so every hidden layer's product runs once over the batch instead of once per critic;
    /// no weight gradient is formed. The groups' sizes follow the data, and a matrix product
    /// of a few rows can round differently on two torch threads than on one (measured with
    /// the bundled PyTorch at 5 to 11 rows), so this runs on one thread whatever the caller
    /// set: the update then gives the same bytes at any thread count.
    pub fn min_action_gradient(&self, pass: &CriticPass, chosen: &Tensor) -> Tensor {
        let threads = tch::get_num_threads();
        if threads > 1 {
            tch::set_num_threads(1);
        }
        let gradient = self.grouped_action_gradient(pass, chosen);
        if threads > 1 {
            tch::set_num_threads(threads);
        }
        gradient
    }

    fn grouped_action_gradient(&self, pass: &CriticPass, chosen: &Tensor) -> Tensor {
        let batch = pass.q.size()[1];
        let last = self.weights.len() - 1;
        let inputs = self.weights[0].size()[1];
        let mut gradient = Tensor::zeros([batch, pass.action_width], (Kind::Float, pass.q.device()));
        for k in 0..2i64 {
            let rows = chosen.eq(k).nonzero().view([-1]);
            let n = rows.size()[0];
            if n == 0 {
                continue;
            }
            // dQ_k / d(input of the output layer): its weights, the same for every row.
            let mut g = self.weights[last].get(k).tr().expand([n, -1], false);
            for l in (0..last).rev() {
                g = pass.inputs[l + 1]
                    .get(k)
                    .index_select(0, &rows)
                    .threshold_backward(&g, 0.0);
                g = g.mm(&self.weights[l].get(k).tr());
            }
            let action_part = g.narrow(1, inputs - pass.action_width, pass.action_width);
            let _ = gradient.index_copy_(0, &rows, &action_part);
        }
        gradient
    }
}

/// What [`TwinCritic`]'s backward passes need of a forward pass.
pub struct CriticPass {
    /// Each layer's input, [2, batch, width]: (s, a) for both networks, then the ReLU outputs.
    inputs: Vec<Tensor>,
    /// Both Q values, [2, batch, 1].
    pub q: Tensor,
    action_width: i64,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn normal_cdf(x: f64) -> f64 {
        0.5 * libm::erfc(-x / std::f64::consts::SQRT_2)
    }

    /// The squashed density integrates (numerically, over a fine grid in a) to the probability the
    /// Gaussian puts on the pre-image interval, i.e. the tanh change of variables is right.
    #[test]
    fn squashed_log_prob_matches_the_numeric_density() {
        for (mean, log_std) in [(0.3f64, -0.5f64), (-1.2, 0.4), (2.5, -1.5)] {
            let density = |a: f64| {
                let u = a.atanh();
                let noise = (u - mean) / log_std.exp();
                let lp = squashed_gaussian_log_prob(
                    &Tensor::from_slice(&[u]).view([1, 1]),
                    &Tensor::from_slice(&[noise]).view([1, 1]),
                    &Tensor::from_slice(&[log_std]).view([1, 1]),
                );
                lp.double_value(&[0, 0]).exp()
            };
            for (lo, hi) in [(-0.9, -0.2), (-0.2, 0.5), (0.5, 0.99)] {
                let n = 4000;
                let h = (hi - lo) / n as f64;
                // Simpson's rule.
                let mut integral = density(lo) + density(hi);
                for k in 1..n {
                    integral += if k % 2 == 1 { 4.0 } else { 2.0 } * density(lo + k as f64 * h);
                }
                integral *= h / 3.0;
                let sigma = log_std.exp();
                let exact = normal_cdf((f64::atanh(hi) - mean) / sigma) - normal_cdf((f64::atanh(lo) - mean) / sigma);
                assert!(
                    (integral - exact).abs() < 1e-6,
                    "mean {mean}, [{lo}, {hi}]: {integral} vs {exact}"
                );
            }
        }
    }

    #[test]
    fn log_prob_stays_finite_where_tanh_saturates() {
        let u = Tensor::from_slice(&[30.0f32, -30.0]).view([1, 2]);
        let lp = squashed_gaussian_log_prob(
            &u,
            &Tensor::zeros([1, 2], (tch::Kind::Float, tch::Device::Cpu)),
            &Tensor::zeros([1, 2], (tch::Kind::Float, tch::Device::Cpu)),
        );
        let v = lp.double_value(&[0, 0]);
        // log(1 - tanh(30)^2) = log(4) - 60 + O(e^-60) per dimension.
        let expected = 2.0 * (-0.5 * (2.0 * std::f64::consts::PI).ln()) - 2.0 * (4f64.ln() - 60.0);
        assert!((v - expected).abs() < 1e-3, "{v} vs {expected}");
    }
}

#[cfg(test)]
mod twin_tests {
    use super::*;
    use tch::{Device, Kind};

    /// Each slice of the stacked critic is an ordinary MLP: recompute Q1 and Q2 layer by layer
    /// with plain matrix products and compare.
    #[test]
    fn twin_critic_equals_two_separate_mlps() {
        tch::manual_seed(3);
        let vs = nn::VarStore::new(Device::Cpu);
        let critic = TwinCritic::new(&vs.root(), 4, 2, &[8, 8]);
        let obs = Tensor::randn([5, 4], (Kind::Float, Device::Cpu));
        let act = Tensor::randn([5, 2], (Kind::Float, Device::Cpu));
        let q = critic.forward(&obs, &act);
        assert_eq!(q.size(), vec![2, 5, 1]);
        let vars = vs.variables();
        for k in 0..2i64 {
            let mut h = Tensor::cat(&[&obs, &act], 1);
            for l in 0..3 {
                let w = vars[&format!("w{l}")].get(k);
                let b = vars[&format!("b{l}")].get(k);
                h = h.matmul(&w) + b;
                if l < 2 {
                    h = h.relu();
                }
            }
            assert!(h.allclose(&q.get(k), 1e-5, 1e-6, false));
        }
        // The two networks were drawn independently.
        assert!(!vars["w1"].get(0).allclose(&vars["w1"].get(1), 1e-3, 1e-3, false));
        let min = critic.min_q(&obs, &act);
        assert!(min.allclose(&q.get(0).minimum(&q.get(1)), 0.0, 0.0, false));
    }

    /// min(Q1, Q2)'s action gradient at the thesis's widths comes out the same to the bit at
    /// one and two torch threads when one critic is the minimum in only a few rows (products
    /// of 5 to 11 rows round by the thread count in the bundled PyTorch), and the caller's
    /// thread count is left as it was.
    #[test]
    fn min_action_gradient_does_not_depend_on_the_thread_count() {
        let _torch = crate::sac::torch_lock();
        tch::manual_seed(4);
        let vs = nn::VarStore::new(Device::Cpu);
        let critic = TwinCritic::new(&vs.root(), 10, 3, &[256, 256]);
        let batch = 256;
        let obs = Tensor::randn([batch, 10], (Kind::Float, Device::Cpu));
        let act = Tensor::randn([batch, 3], (Kind::Float, Device::Cpu));
        let pass = tch::no_grad(|| critic.forward_recorded(&obs, &act));
        for few in 1..=16 {
            let chosen = Tensor::zeros([batch], (Kind::Int64, Device::Cpu));
            let _ = chosen.narrow(0, 0, few).fill_(1);
            let [one, two] = [1, 2].map(|threads| {
                tch::set_num_threads(threads);
                let gradient = tch::no_grad(|| critic.min_action_gradient(&pass, &chosen));
                assert_eq!(tch::get_num_threads(), threads);
                gradient
            });
            assert!(one.equal(&two), "{few} rows from the second critic");
        }
        tch::set_num_threads(1);
    }
}
