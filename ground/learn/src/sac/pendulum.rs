//! The standard sanity task for a continuous-control learner: Gymnasium's Pendulum-v1 (swing up
//! and balance), re-implemented with its exact constants so scores compare with published SAC
//! results (about -150 to -200 mean episode reward once solved).

use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};

use super::agent::Sac;
use super::replay::{sampler, ReplayBuffer};
use super::trainer::{mean_std, run, Episodic, LoopOptions, LoopState, StepOutcome, TrainObserver, WarmupPolicy};
use super::SacConfig;

/// Observation: cos and sin of the angle from upright, angular rate (rad/s).
pub const OBS_DIM: usize = 3;
/// Action: torque as a fraction of the 2 N m limit.
pub const ACT_DIM: usize = 1;
/// Steps per episode (10 s of 0.05 s steps), a time limit, not a terminal state.
pub const EPISODE_STEPS: u32 = 200;
const MAX_SPEED: f64 = 8.0;
const MAX_TORQUE: f64 = 2.0;
const DT: f64 = 0.05;
const GRAVITY: f64 = 10.0;
const MASS: f64 = 1.0;
const LENGTH: f64 = 1.0;

/// Pendulum-v1: angle from upright, angular rate; the action in [-1, 1] scales the torque limit.
#[derive(Debug, Clone)]
pub struct Pendulum {
    angle: f64,
    rate: f64,
    steps: u32,
    seed: u64,
    rng: ChaCha8Rng,
}

fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * ((rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
}

/// Angle wrapped to [-pi, pi).
fn wrap(angle: f64) -> f64 {
    (angle + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
}

impl Pendulum {
    /// A pendulum drawing from `seed`, already reset to a random state.
    pub fn new(seed: u64) -> Self {
        let mut p = Self {
            angle: 0.0,
            rate: 0.0,
            steps: 0,
            seed,
            rng: ChaCha8Rng::seed_from_u64(seed),
        };
        p.reset();
        p
    }

    /// A new episode: angle uniform in [-pi, pi), rate uniform in [-1, 1] rad/s; its observation.
    pub fn reset(&mut self) -> [f32; OBS_DIM] {
        self.angle = uniform(&mut self.rng, -std::f64::consts::PI, std::f64::consts::PI);
        self.rate = uniform(&mut self.rng, -1.0, 1.0);
        self.steps = 0;
        self.observation()
    }

    /// [cos angle, sin angle, angular rate].
    pub fn observation(&self) -> [f32; OBS_DIM] {
        [self.angle.cos() as f32, self.angle.sin() as f32, self.rate as f32]
    }

    /// One 0.05 s step: (observation, reward, episode over). The episode ends by time limit only,
    /// so the learner must still bootstrap from the last state (it is not terminal).
    pub fn step(&mut self, action: f32) -> ([f32; OBS_DIM], f64, bool) {
        let torque = (f64::from(action) * MAX_TORQUE).clamp(-MAX_TORQUE, MAX_TORQUE);
        let cost = wrap(self.angle).powi(2) + 0.1 * self.rate.powi(2) + 0.001 * torque.powi(2);
        let accel = 3.0 * GRAVITY / (2.0 * LENGTH) * self.angle.sin() + 3.0 / (MASS * LENGTH * LENGTH) * torque;
        self.rate = (self.rate + accel * DT).clamp(-MAX_SPEED, MAX_SPEED);
        self.angle += self.rate * DT;
        self.steps += 1;
        (self.observation(), -cost, self.steps >= EPISODE_STEPS)
    }
}

impl Episodic for Pendulum {
    fn obs_dim(&self) -> usize {
        OBS_DIM
    }

    fn act_dim(&self) -> usize {
        ACT_DIM
    }

    type Error = core::convert::Infallible;

    fn reset(&mut self, episode: u64) -> Result<Vec<f32>, Self::Error> {
        self.rng = ChaCha8Rng::seed_from_u64(self.seed);
        self.rng.set_stream(episode);
        Ok(Pendulum::reset(self).to_vec())
    }

    fn step(&mut self, action: &[f32]) -> StepOutcome {
        let (obs, reward, over) = Pendulum::step(self, action.first().copied().unwrap_or(0.0));
        StepOutcome {
            obs: obs.to_vec(),
            reward,
            terminal: false,
            truncated: over,
        }
    }
}

/// Mean episode reward of the deterministic policy over `episodes` fixed evaluation episodes.
pub fn evaluate(agent: &Sac, episodes: u64, seed: u64) -> (f64, f64) {
    let mut env = Pendulum::new(seed ^ 0x5eed_e7a1);
    let rewards: Vec<f64> = (0..episodes)
        .map(|e| {
            let Ok(mut obs) = Episodic::reset(&mut env, e);
            let mut total = 0.0;
            loop {
                let out = Episodic::step(&mut env, &agent.act(&obs, 1));
                total += out.reward;
                if out.truncated {
                    break total;
                }
                obs = out.obs;
            }
        })
        .collect();
    mean_std(&rewards)
}

/// One point of the sanity run's learning curve.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CurvePoint {
    /// Environment steps trained when evaluated.
    pub env_steps: u64,
    /// Mean episode reward of the 10 deterministic evaluation episodes.
    pub mean_reward: f64,
    /// Their standard deviation.
    pub std_reward: f64,
    /// Wall-clock seconds since training started.
    pub seconds: f64,
}

/// Trains SAC on the pendulum for `steps` environment steps (1 update per step after
/// `config.warmup_steps`), evaluating 10 episodes every `eval_every` steps.
pub fn sanity_run(config: SacConfig, steps: u64, eval_every: u64, seed: u64) -> Vec<CurvePoint> {
    struct Curve {
        start: std::time::Instant,
        seed: u64,
        points: Vec<CurvePoint>,
        bar: indicatif::ProgressBar,
    }
    impl TrainObserver for Curve {
        fn evaluate(&mut self, env_steps: u64, agent: &Sac) {
            let (mean_reward, std_reward) = evaluate(agent, 10, self.seed);
            self.points.push(CurvePoint {
                env_steps,
                mean_reward,
                std_reward,
                seconds: self.start.elapsed().as_secs_f64(),
            });
            self.bar.set_position(env_steps);
            self.bar.set_message(format!("eval {mean_reward:.0}"));
        }
    }
    tch::manual_seed(seed as i64);
    let mut agent = Sac::new(config.clone(), OBS_DIM, ACT_DIM, tch::Device::Cpu);
    agent.noise_seed = seed;
    let mut buffer = ReplayBuffer::new(OBS_DIM, ACT_DIM, config.replay_capacity);
    let mut env = Pendulum::new(seed);
    let bar = ground_core::progress::bar(steps, "pendulum {bar:40} {pos}/{len} steps {msg} [{elapsed}]");
    let mut curve = Curve {
        start: std::time::Instant::now(),
        seed,
        points: Vec::new(),
        bar,
    };
    let options = LoopOptions {
        total_steps: steps,
        eval_every,
        checkpoint_every: 0,
        warmup: WarmupPolicy::Random,
    };
    // The pendulum always resets: its error type is uninhabited.
    let Ok(()) = run(
        &mut env,
        &mut agent,
        &mut buffer,
        &mut LoopState::default(),
        &mut sampler(seed),
        &options,
        &mut curve,
    );
    curve.bar.finish();
    curve.points
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upright_at_rest_is_an_equilibrium_with_zero_cost() {
        let mut p = Pendulum::new(0);
        p.angle = 0.0;
        p.rate = 0.0;
        let (obs, reward, _) = p.step(0.0);
        assert_eq!(reward, 0.0);
        assert_eq!(obs, [1.0, 0.0, 0.0]);
    }

    #[test]
    fn free_swing_from_small_angle_matches_the_linearised_period() {
        // Small oscillations about the bottom: theta'' = -(3g/2l) phi, period 2 pi / sqrt(15).
        let mut p = Pendulum::new(0);
        p.angle = std::f64::consts::PI + 0.01;
        p.rate = 0.0;
        let mut crossings = Vec::new();
        let mut prev = wrap(p.angle - std::f64::consts::PI);
        for k in 1..2000 {
            p.step(0.0);
            let phi = wrap(p.angle - std::f64::consts::PI);
            if prev > 0.0 && phi <= 0.0 {
                crossings.push(k as f64 * DT);
            }
            prev = phi;
            p.steps = 0;
        }
        let period = (crossings[crossings.len() - 1] - crossings[0]) / (crossings.len() - 1) as f64;
        let expected = 2.0 * std::f64::consts::PI / 15f64.sqrt();
        // Semi-implicit Euler at dt = 0.05 shifts the period by O(dt^2 omega^2) ~ 1%.
        assert!((period - expected).abs() < 0.03 * expected, "{period} vs {expected}");
    }

    #[test]
    fn episode_ends_after_200_steps() {
        let mut p = Pendulum::new(1);
        let ends: Vec<bool> = (0..EPISODE_STEPS).map(|_| p.step(0.3).2).collect();
        assert!(ends[..199].iter().all(|e| !e) && ends[199]);
    }
}
