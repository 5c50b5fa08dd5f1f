//! Throughput of the learner: gradient updates per second at given network sizes, and the
//! fraction of the machine's measured GEMM rate they reach.

use std::time::Instant;

use tch::{Device, Kind, Tensor};

use super::agent::Sac;
use super::replay::{sampler, ReplayBuffer, Transition};
use super::SacConfig;

/// Floating-point operations of one update (forward + backward multiply-adds of every linear
/// layer touched), counted from the layer shapes.
pub fn update_flops(obs_dim: usize, act_dim: usize, hidden: &[usize], batch: usize) -> f64 {
    let mlp = |input: usize, output: usize| -> f64 {
        let mut widths = vec![input];
        widths.extend_from_slice(hidden);
        widths.push(output);
        widths.windows(2).map(|w| 2.0 * (w[0] * w[1]) as f64).sum::<f64>() * batch as f64
    };
    let actor = mlp(obs_dim, 2 * act_dim);
    let critic = mlp(obs_dim + act_dim, 1);
    // Target: actor forward + 2 target critics forward. Critic step: 2 critics, forward (1x)
    // and backward (2x: input and weight gradients). Actor step: actor forward, 2 critics
    // forward, backward through the critics to the action only (1x, weights frozen), actor
    // backward (2x). Total 4 actor + 12 critic forward passes.
    let target = actor + 2.0 * critic;
    let critic_step = 2.0 * 3.0 * critic;
    let actor_step = actor + 2.0 * critic + 2.0 * critic + 2.0 * actor;
    target + critic_step + actor_step
}

/// Measured GEMM rate (GFLOP/s) of a square n x n x n product on `device`, median of `reps`
/// (reading one element back waits for the product on a GPU).
pub fn gemm_gflops(n: i64, reps: usize, device: Device) -> f64 {
    let a = Tensor::randn([n, n], (Kind::Float, device));
    let b = Tensor::randn([n, n], (Kind::Float, device));
    let mut times = Vec::with_capacity(reps);
    for _ in 0..reps {
        let t = Instant::now();
        let c = a.matmul(&b);
        let _ = c.double_value(&[0, 0]);
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    2.0 * (n * n * n) as f64 / times[reps / 2] / 1e9
}

/// Updates timed together; the figure is the median block, so a burst of other work on the
/// machine moves it less than a mean over the whole run.
pub const BLOCK: usize = 100;

/// Seconds per update on `device`, batch sampling included: the median over blocks of [`BLOCK`]
/// updates (`updates` rounded up to whole blocks, after 20 warm-up updates). The replay buffer
/// holds 10,000 transitions of standard normal observations, uniform actions in [-1, 1] and
/// uniform rewards in [-1, 0], as Stable-Baselines3's reference bench feeds its learner random
/// observations: identical rows would leave most hidden units dead for the whole batch, which
/// no training data does.
pub fn seconds_per_update(config: &SacConfig, obs_dim: usize, act_dim: usize, updates: usize, device: Device) -> f64 {
    tch::manual_seed(0);
    let mut sac = Sac::new(config.clone(), obs_dim, act_dim, device);
    seconds_per_update_of(&mut sac, obs_dim, act_dim, 0, updates, false)
}

/// [`seconds_per_update`] of a given learner of `obs_dim` and `act_dim` (its own settings and
/// losses, its weights trained on), every `demonstration_every`-th transition of the buffer a
/// demonstration (0: none), so that a behaviour-cloning term has rows to work on; with
/// `cloning_only`, its actor-only cloning update ([`Sac::cloning_update`], as `cloning_only`
/// relabelling rounds run) instead of the SAC update.
pub fn seconds_per_update_of(
    sac: &mut Sac,
    obs_dim: usize,
    act_dim: usize,
    demonstration_every: usize,
    updates: usize,
    cloning_only: bool,
) -> f64 {
    let config = sac.config.clone();
    let mut buffer = ReplayBuffer::new(obs_dim, act_dim, 10_000);
    let mut draws = firmware_sim::dispersion::Normal::new(0, 0);
    for k in 0..10_000 {
        let obs: Vec<f32> = (0..obs_dim).map(|_| draws.sample() as f32).collect();
        let next_obs: Vec<f32> = (0..obs_dim).map(|_| draws.sample() as f32).collect();
        let action: Vec<f32> = (0..act_dim).map(|_| (2.0 * draws.unit() - 1.0) as f32).collect();
        buffer.push(&Transition {
            obs: &obs,
            action: &action,
            reward: -draws.unit() as f32,
            next_obs: &next_obs,
            done: k % 50 == 0,
            demonstration: demonstration_every > 0 && k % demonstration_every == 0,
        });
    }
    let mut rng = sampler(0);
    for _ in 0..20 {
        sac.update(&buffer.sample(config.batch_size, &mut rng));
    }
    let mut blocks: Vec<f64> = (0..updates.div_ceil(BLOCK).max(1))
        .map(|_| {
            let t = Instant::now();
            for _ in 0..BLOCK {
                let batch = buffer.sample(config.batch_size, &mut rng);
                if cloning_only {
                    sac.cloning_update(&batch);
                } else {
                    sac.update(&batch);
                }
            }
            t.elapsed().as_secs_f64() / BLOCK as f64
        })
        .collect();
    blocks.sort_by(f64::total_cmp);
    blocks[blocks.len() / 2]
}
