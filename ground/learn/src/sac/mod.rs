//! Soft Actor-Critic (Haarnoja et al. 2018, automatic temperature), written to be read top to
//! bottom in [`agent::Sac::update`]. Hyper-parameters default to the thesis (docs/spec.md section 8).

pub mod adam;
pub mod agent;
pub mod bench;
pub mod networks;
pub mod pendulum;
pub mod replay;
pub mod trainer;

use serde::{Deserialize, Serialize};

/// libtorch's random generator and thread pool are process-wide: the unit tests that use them
/// take turns (a parallel test would draw from the same stream and break determinism), and use
/// one intra-op thread (OpenMP workers of parallel tests oversubscribe two cores).
#[cfg(test)]
pub(crate) fn torch_lock() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let guard = LOCK.lock().unwrap_or_else(|e| e.into_inner());
    tch::set_num_threads(1);
    guard
}

/// Makes glibc keep freed large blocks for reuse. A SAC update allocates and frees tensors of
/// 0.25-0.5 MB; above glibc's mmap threshold each one is a fresh mmap whose pages fault in on
/// first touch and go back with munmap on free. Measured with perf: kernel page-fault handling
/// and malloc took about 14% of an update. Process-wide and idempotent; call it once at start.
pub fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator parameters; both values are valid for glibc.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
    }
}

/// The first CUDA device, or why libtorch cannot use one here. The linker drops
/// `libtorch_cuda.so` from the binary's needs (nothing names its symbols), and without it
/// libtorch sees no GPU even on a CUDA build; it is loaded here on first call, from the binary's
/// libtorch folder (its runpath) or `LD_LIBRARY_PATH`. A CPU-only libtorch has no such library.
pub fn cuda_device() -> Result<tch::Device, String> {
    static LOADED: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    LOADED.get_or_init(load_torch_cuda).clone()?;
    if tch::Cuda::is_available() {
        Ok(tch::Device::Cuda(0))
    } else {
        Err("libtorch finds no CUDA device here (no GPU, or no driver)".into())
    }
}

#[cfg(target_os = "linux")]
fn load_torch_cuda() -> Result<(), String> {
    // SAFETY: dlopen of a library by name with a valid C string; the handle is kept for the life
    // of the process (never closed), so the CUDA hooks its initialisers register stay valid.
    // dlerror's message, when there is one, is a valid C string until the next dl call.
    unsafe {
        if libc::dlopen(c"libtorch_cuda.so".as_ptr(), libc::RTLD_NOW | libc::RTLD_GLOBAL).is_null() {
            let reason = libc::dlerror();
            let reason = if reason.is_null() {
                "unknown reason".into()
            } else {
                std::ffi::CStr::from_ptr(reason).to_string_lossy().into_owned()
            };
            return Err(format!(
                "libtorch_cuda.so does not load (a CPU-only PyTorch?): {reason}"
            ));
        }
    }
    Ok(())
}

#[cfg(not(target_os = "linux"))]
fn load_torch_cuda() -> Result<(), String> {
    Ok(())
}

/// The learner's hyper-parameters (docs/spec.md section 8); defaults are the thesis's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SacConfig {
    /// Hidden layer widths, shared by the actor and both critics.
    pub hidden: Vec<usize>,
    /// Adam learning rate of the actor, the critics and the temperature (default 3e-4; > 0).
    pub learning_rate: f64,
    /// Discount factor gamma per environment step, in [0, 1) (default 0.99).
    pub discount: f64,
    /// Polyak factor of the target critics, applied after every update.
    pub target_smoothing: f64,
    /// Transitions per gradient update's mini-batch (default 256).
    pub batch_size: usize,
    /// Transitions the replay buffer holds; once full, the oldest is overwritten (default 1,000,000).
    pub replay_capacity: usize,
    /// Environment steps before the first gradient update.
    pub warmup_steps: u64,
    /// Gradient updates per environment step.
    pub updates_per_step: u32,
    /// Entropy target; `None` means minus the action dimension (-3 here).
    pub target_entropy: Option<f64>,
    /// Initial log alpha, the entropy temperature's logarithm (default 0: alpha = 1).
    pub initial_log_temperature: f64,
    /// Upper bound on log alpha (None = unbounded, the thesis). Behaviour cloning pins the mean
    /// action at the demonstrations' clipped extremes (+-0.999), where the tanh squash makes the
    /// entropy target unreachable; Adam then raises log alpha by about the learning rate every
    /// update, without end (alpha 44 after 20k pretraining updates, measured), and the critics'
    /// soft targets diverge with it (Q ~ 2e3). A low bound (log alpha <= -5, with the initial
    /// value there too) keeps them on the data and lets RL improve the pretrained actor; 0 only
    /// slows the divergence (measured, README).
    pub max_log_temperature: Option<f64>,
    /// Weight of the behaviour-cloning term on demonstration tuples (0 = plain SAC, the thesis).
    /// The actor loss becomes  lambda * (alpha log pi - Q) + bc * E(tanh(mean), a_demo)  with
    /// lambda = 1 / mean|Q| (TD3+BC's normalisation), so `bc` is scale-free, and E the agent's
    /// cloning error (`agent::CloningLoss`; by default |tanh(mean) - a_demo|^2).
    pub behaviour_cloning: f64,
    /// Polyak factor of an averaged copy of the actor's weights, updated after every actor step
    /// (0 = none, the thesis). When set, the average is what deterministic actions, evaluations,
    /// best checkpoints and the onboard export use: at a fixed learning rate the iterates wander
    /// around the optimum of the behaviour-cloning loss, and their average sits closer to it
    /// (Polyak-Ruppert averaging). Exploration keeps the online actor.
    pub actor_averaging: f64,
}

impl Default for SacConfig {
    fn default() -> Self {
        Self {
            hidden: vec![256, 256],
            learning_rate: 3e-4,
            discount: 0.99,
            target_smoothing: 0.005,
            batch_size: 256,
            replay_capacity: 1_000_000,
            warmup_steps: 50_000,
            updates_per_step: 1,
            target_entropy: None,
            initial_log_temperature: 0.0,
            max_log_temperature: None,
            behaviour_cloning: 0.0,
            actor_averaging: 0.0,
        }
    }
}

/// Why [`SacConfig::validate`] refused a config.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SacConfigError {
    /// A setting that must be positive and finite (`learning_rate`) is not.
    #[error("sac.{name} must be positive and finite, got {value}")]
    NotPositive {
        /// The key, without `sac.`.
        name: &'static str,
        /// The refused value.
        value: f64,
    },
    /// `discount` is outside [0, 1).
    #[error("sac.discount must be in [0, 1), got {0}")]
    Discount(f64),
    /// `target_smoothing` is outside (0, 1].
    #[error("sac.target_smoothing must be in (0, 1], got {0}")]
    TargetSmoothing(f64),
    /// `hidden` is empty or lists a zero width.
    #[error("sac.hidden must list positive widths, got {0:?}")]
    Hidden(Vec<usize>),
    /// `batch_size`, `replay_capacity` or `updates_per_step` is 0.
    #[error("sac.batch_size, sac.replay_capacity and sac.updates_per_step must be positive")]
    ZeroSize,
    /// `behaviour_cloning` is negative or not finite.
    #[error("sac.behaviour_cloning must be >= 0, got {0}")]
    BehaviourCloning(f64),
    /// `actor_averaging` is outside [0, 1].
    #[error("sac.actor_averaging must be in [0, 1] (0 = off), got {0}")]
    ActorAveraging(f64),
    /// `initial_log_temperature` is above `max_log_temperature`.
    #[error("sac.initial_log_temperature ({initial}) is above sac.max_log_temperature ({cap:?})")]
    TemperatureAboveCap {
        /// The initial log alpha.
        initial: f64,
        /// The cap on log alpha.
        cap: Option<f64>,
    },
    /// `initial_log_temperature`, `target_entropy` or `max_log_temperature` is NaN or infinite.
    #[error("sac.initial_log_temperature, sac.target_entropy and sac.max_log_temperature must be finite")]
    NotFinite,
}

impl SacConfig {
    /// Refuses values no run could use, before any work starts.
    pub fn validate(&self) -> Result<(), SacConfigError> {
        let positive = |name: &'static str, value: f64| {
            if value.is_finite() && value > 0.0 {
                Ok(())
            } else {
                Err(SacConfigError::NotPositive { name, value })
            }
        };
        positive("learning_rate", self.learning_rate)?;
        if !(0.0..1.0).contains(&self.discount) {
            return Err(SacConfigError::Discount(self.discount));
        }
        if !(self.target_smoothing > 0.0 && self.target_smoothing <= 1.0) {
            return Err(SacConfigError::TargetSmoothing(self.target_smoothing));
        }
        if self.hidden.is_empty() || self.hidden.contains(&0) {
            return Err(SacConfigError::Hidden(self.hidden.clone()));
        }
        if self.batch_size == 0 || self.replay_capacity == 0 || self.updates_per_step == 0 {
            return Err(SacConfigError::ZeroSize);
        }
        if !(self.behaviour_cloning.is_finite() && self.behaviour_cloning >= 0.0) {
            return Err(SacConfigError::BehaviourCloning(self.behaviour_cloning));
        }
        if !(0.0..=1.0).contains(&self.actor_averaging) {
            return Err(SacConfigError::ActorAveraging(self.actor_averaging));
        }
        if self
            .max_log_temperature
            .is_some_and(|cap| self.initial_log_temperature > cap)
        {
            return Err(SacConfigError::TemperatureAboveCap {
                initial: self.initial_log_temperature,
                cap: self.max_log_temperature,
            });
        }
        if !self.initial_log_temperature.is_finite()
            || self.target_entropy.is_some_and(|t| !t.is_finite())
            || self.max_log_temperature.is_some_and(|t| !t.is_finite())
        {
            return Err(SacConfigError::NotFinite);
        }
        Ok(())
    }
}
