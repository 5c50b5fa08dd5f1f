//! The MDPs from Python: `Env` (one episode at a time) and `VecEnv` (many, stepped in
//! parallel in one call with the GIL released). Both are `ground_core::env::MdpEnv` itself, so
//! their transitions are the Rust environments' bit for bit.

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;

use ground_core::env::{EnvConfig, Environment, MdpEnv, Planar, Problem, Step};
use ground_core::with_problem;
use onboard::dynamics::SpacecraftState;
use onboard::features::ACTION_LEN;
use shared::mission::MissionFamily;
use shared::scenario::Scenario;

use crate::{refused, scenario_family};

/// `(observation, reward, done, info)` of `Env.step`.
type StepResult<'py> = (Bound<'py, PyArray1<f32>>, f64, bool, Bound<'py, PyDict>);
/// `(observations, rewards, done)` of `VecEnv.step`.
type VecStepResult<'py> = (
    Bound<'py, PyArray2<f32>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<bool>>,
);
/// `(observations, rewards)` of a whole flight.
type Rollout<'py> = (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray1<f64>>);

/// What a step gave, problem-independent.
struct Transition {
    observation: Vec<f32>,
    features: Vec<f64>,
    reward: f64,
    done: bool,
    dr: f64,
    dv: f64,
    throttle: f64,
    state: SpacecraftState,
    base_reward: f64,
    terminal_term: f64,
}

/// One environment of either problem, behind one interface (the problem's feature count is
/// a property, not a type, on this side).
trait AnyEnv: Send + Sync {
    fn reset(&mut self, scenario: &Scenario) -> Result<Vec<f32>, String>;
    fn step(&mut self, action: &[f32; ACTION_LEN]) -> Result<Transition, String>;
    fn features(&self) -> Option<Vec<f64>>;
    fn observation(&self) -> Option<Vec<f32>>;
    fn state(&self) -> Option<SpacecraftState>;
    fn obs_dim(&self) -> usize;
    fn is_done(&self) -> bool;
}

impl<P: Problem<Geometry = Planar>> AnyEnv for MdpEnv<P> {
    fn reset(&mut self, scenario: &Scenario) -> Result<Vec<f32>, String> {
        Environment::reset(self, scenario)
            .map(|o| o.as_ref().to_vec())
            .map_err(|e| e.to_string())
    }

    fn step(&mut self, action: &[f32; ACTION_LEN]) -> Result<Transition, String> {
        let Step {
            observation,
            reward,
            done,
            info,
        } = Environment::step(self, action).map_err(|e| e.to_string())?;
        Ok(Transition {
            observation: observation.as_ref().to_vec(),
            features: self.features().map_or_else(Vec::new, |f| f.as_ref().to_vec()),
            reward,
            done,
            dr: info.residuals.position,
            dv: info.residuals.velocity,
            throttle: info.throttle,
            state: info.state,
            base_reward: info.base_reward,
            terminal_term: info.terminal_term,
        })
    }

    fn features(&self) -> Option<Vec<f64>> {
        MdpEnv::features(self).map(|f| f.as_ref().to_vec())
    }

    fn observation(&self) -> Option<Vec<f32>> {
        Environment::observation(self).map(|o| o.as_ref().to_vec())
    }

    fn state(&self) -> Option<SpacecraftState> {
        Environment::state(self)
    }

    fn obs_dim(&self) -> usize {
        P::OBS
    }

    fn is_done(&self) -> bool {
        Environment::is_done(self)
    }
}

/// A new environment of `family`'s problem, with the `[env]` settings of a config (TOML text;
/// none: the defaults), its spacecraft in the family's units.
fn new_env(family: &MissionFamily, config: &EnvConfig) -> PyResult<Box<dyn AnyEnv>> {
    let config = EnvConfig {
        body: family.body,
        ..*config
    };
    with_problem!(family.problem, P => MdpEnv::<P>::new(&config).map(|e| Box::new(e) as Box<dyn AnyEnv>))
        .map_err(refused)
}

fn env_config(text: Option<&str>) -> PyResult<EnvConfig> {
    match text {
        None => Ok(EnvConfig::default()),
        Some(text) => toml::from_str(text).map_err(|e| refused(format!("env config: {e}"))),
    }
}

fn state_array(state: &SpacecraftState) -> [f64; 5] {
    [state.r[0], state.r[1], state.v[0], state.v[1], state.m]
}

/// The action as the environment takes it: three finite components.
fn action_of(action: &[f32]) -> PyResult<[f32; ACTION_LEN]> {
    let action: [f32; ACTION_LEN] = action
        .try_into()
        .map_err(|_| refused(format!("an action has {ACTION_LEN} components, not {}", action.len())))?;
    if !action.iter().all(|a| a.is_finite()) {
        return Err(refused("the action has a NaN or infinite component"));
    }
    Ok(action)
}

/// One episode at a time of a scenario distribution's MDP (docs/spec.md sections 4 to 6):
/// `reset(seed, index)` starts scenario `index` of the stream `seed`, `step(action)` flies one
/// guidance cycle.
#[pyclass(module = "lowthrust._lowthrust")]
pub struct Env {
    kind: MissionFamily,
    env: Box<dyn AnyEnv>,
    steps: u32,
}

#[pymethods]
impl Env {
    /// `Env(kind, env_config=None)`: `kind` one of `SCENARIOS`, a mission file's path or a
    /// mission table as TOML text (docs/missions.md); `env_config` the `[env]` section of a
    /// project config as TOML text (spacecraft, reward, terminal term, integrator).
    #[new]
    #[pyo3(signature = (kind, env_config=None))]
    fn new(kind: &str, env_config: Option<&str>) -> PyResult<Self> {
        let kind = scenario_family(kind)?;
        let config = self::env_config(env_config)?;
        Ok(Self {
            kind,
            env: new_env(&kind, &config)?,
            steps: 0,
        })
    }

    /// Starts scenario `index` of the stream `seed`; returns the observation (float32).
    fn reset<'py>(&mut self, py: Python<'py>, seed: u64, index: u64) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let scenario = self.kind.draw(seed, index);
        let obs = self.env.reset(&scenario).map_err(refused)?;
        self.steps = scenario.steps;
        Ok(PyArray1::from_vec(py, obs))
    }

    /// One step under `action` (three float32 in [-1, 1]; outside is clamped): returns
    /// `(observation, reward, done, info)`, info with the features (float64), the residuals
    /// `dr`, `dv`, the throttle flown, the state `[x, y, vx, vy, m]` and the reward's parts.
    fn step<'py>(&mut self, py: Python<'py>, action: PyReadonlyArray1<'py, f32>) -> PyResult<StepResult<'py>> {
        let action = action_of(action.as_slice()?)?;
        let t = self.env.step(&action).map_err(refused)?;
        let info = PyDict::new(py);
        info.set_item("features", PyArray1::from_vec(py, t.features))?;
        info.set_item("dr", t.dr)?;
        info.set_item("dv", t.dv)?;
        info.set_item("throttle", t.throttle)?;
        info.set_item("mass", t.state.m)?;
        info.set_item("state", PyArray1::from_slice(py, &state_array(&t.state)))?;
        info.set_item("base_reward", t.base_reward)?;
        info.set_item("terminal_term", t.terminal_term)?;
        Ok((PyArray1::from_vec(py, t.observation), t.reward, t.done, info))
    }

    /// Number of observation features (10 transfer, 22 rendezvous).
    #[getter]
    fn obs_dim(&self) -> usize {
        self.env.obs_dim()
    }

    /// Steps N of the current episode (0 before the first reset).
    #[getter]
    fn steps(&self) -> u32 {
        self.steps
    }

    /// Whether the current episode has taken its N steps.
    #[getter]
    fn done(&self) -> bool {
        self.env.is_done()
    }

    /// The current features in float64 (None before the first reset).
    #[getter]
    fn features<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.env.features().map(|f| PyArray1::from_vec(py, f))
    }

    /// The current state `[x, y, vx, vy, m]` (AU, AU/t*, m0; None before the first reset).
    #[getter]
    fn state<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.env.state().map(|s| PyArray1::from_slice(py, &state_array(&s)))
    }
}

/// `num_envs` episodes of one scenario distribution stepped together: one call steps every
/// episode, in parallel in Rust with the GIL released. No autoreset: the Python wrapper resets
/// finished episodes (`reset` with a mask).
#[pyclass(module = "lowthrust._lowthrust")]
pub struct VecEnv {
    kind: MissionFamily,
    envs: Vec<Box<dyn AnyEnv>>,
    obs_dim: usize,
}

#[pymethods]
impl VecEnv {
    /// `VecEnv(kind, num_envs, env_config=None)`, as `Env`.
    #[new]
    #[pyo3(signature = (kind, num_envs, env_config=None))]
    fn new(kind: &str, num_envs: usize, env_config: Option<&str>) -> PyResult<Self> {
        let kind = scenario_family(kind)?;
        if num_envs == 0 {
            return Err(refused("num_envs must be at least 1"));
        }
        let config = self::env_config(env_config)?;
        let envs = (0..num_envs)
            .map(|_| new_env(&kind, &config))
            .collect::<PyResult<Vec<_>>>()?;
        let obs_dim = envs[0].obs_dim();
        Ok(Self { kind, envs, obs_dim })
    }

    /// Starts episode i on scenario `indices[i]` of the stream `seed`, for every i where `mask`
    /// (default: all) is true; returns every episode's observation, `(num_envs, obs_dim)`.
    #[pyo3(signature = (seed, indices, mask=None))]
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        seed: u64,
        indices: PyReadonlyArray1<'py, u64>,
        mask: Option<PyReadonlyArray1<'py, bool>>,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let n = self.envs.len();
        let indices = indices.as_slice()?;
        if indices.len() != n {
            return Err(refused(format!("{} indices for {n} episodes", indices.len())));
        }
        let mask = match &mask {
            Some(m) if m.len() != n => return Err(refused(format!("a mask of {} for {n} episodes", m.len()))),
            Some(m) => m.as_slice()?.to_vec(),
            None => vec![true; n],
        };
        let kind = self.kind;
        let obs_dim = self.obs_dim;
        let indices = indices.to_vec();
        let envs = &mut self.envs;
        let flat = py
            .detach(|| -> Result<Vec<f32>, String> {
                let rows: Vec<Vec<f32>> = envs
                    .par_iter_mut()
                    .zip(indices.par_iter().zip(mask.par_iter()))
                    .map(|(env, (&index, &reset))| {
                        if reset {
                            env.reset(&kind.draw(seed, index))
                        } else {
                            env.observation()
                                .ok_or_else(|| "an episode never reset is masked out".to_string())
                        }
                    })
                    .collect::<Result<_, String>>()?;
                Ok(rows.concat())
            })
            .map_err(refused)?;
        let array = Array2::from_shape_vec((n, obs_dim), flat).map_err(refused)?;
        Ok(array.into_pyarray(py))
    }

    /// Steps every episode under its row of `actions` `(num_envs, 3)` float32, or those where
    /// `mask` is true (the others keep their state and report their observation, reward 0):
    /// returns `(observations (num_envs, obs_dim) float32, rewards (num_envs,) float64, done
    /// (num_envs,) bool)`. A finished episode must be reset first.
    #[pyo3(signature = (actions, mask=None))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        actions: PyReadonlyArray2<'py, f32>,
        mask: Option<PyReadonlyArray1<'py, bool>>,
    ) -> PyResult<VecStepResult<'py>> {
        let n = self.envs.len();
        if actions.shape() != [n, ACTION_LEN] {
            return Err(refused(format!(
                "actions of shape {:?} for {n} episodes of {ACTION_LEN} components",
                actions.shape()
            )));
        }
        let mask = match &mask {
            Some(m) if m.len() != n => return Err(refused(format!("a mask of {} for {n} episodes", m.len()))),
            Some(m) => m.as_slice()?.to_vec(),
            None => vec![true; n],
        };
        let actions = actions.as_slice()?;
        let actions: Vec<[f32; ACTION_LEN]> = actions
            .chunks_exact(ACTION_LEN)
            .map(action_of)
            .collect::<PyResult<_>>()?;
        let envs = &mut self.envs;
        // (observation, reward, done) of each episode.
        let steps = py
            .detach(|| {
                envs.par_iter_mut()
                    .zip(actions.par_iter().zip(mask.par_iter()))
                    .enumerate()
                    .map(|(i, (env, (action, &stepping)))| {
                        if stepping {
                            let t = env.step(action).map_err(|e| format!("episode {i}: {e}"))?;
                            Ok((t.observation, t.reward, t.done))
                        } else {
                            let obs = env.observation().ok_or(format!("episode {i} was never reset"))?;
                            Ok((obs, 0.0, false))
                        }
                    })
                    .collect::<Result<Vec<(Vec<f32>, f64, bool)>, String>>()
            })
            .map_err(refused)?;
        let mut obs = Vec::with_capacity(n * self.obs_dim);
        let (mut rewards, mut done) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for (observation, reward, finished) in steps {
            obs.extend_from_slice(&observation);
            rewards.push(reward);
            done.push(finished);
        }
        let obs = Array2::from_shape_vec((n, self.obs_dim), obs).map_err(refused)?;
        Ok((
            obs.into_pyarray(py),
            PyArray1::from_vec(py, rewards),
            PyArray1::from_vec(py, done),
        ))
    }

    /// Number of episodes.
    #[getter]
    fn num_envs(&self) -> usize {
        self.envs.len()
    }

    /// Number of observation features.
    #[getter]
    fn obs_dim(&self) -> usize {
        self.obs_dim
    }
}

/// Scenario `index` of the stream `seed` flown under `actions` `(k, 3)` by the Rust
/// environment driven from Rust (no Python between the steps): observations `(k + 1,
/// obs_dim)` and rewards `(k,)`. The reference the Python environments are checked against.
#[pyfunction]
#[pyo3(signature = (kind, seed, index, actions, env_config=None))]
fn reference_rollout<'py>(
    py: Python<'py>,
    kind: &str,
    seed: u64,
    index: u64,
    actions: PyReadonlyArray2<'py, f32>,
    env_config: Option<&str>,
) -> PyResult<Rollout<'py>> {
    let kind = scenario_family(kind)?;
    let mut env = new_env(&kind, &self::env_config(env_config)?)?;
    if actions.shape()[1] != ACTION_LEN {
        return Err(refused("actions must be (k, 3)"));
    }
    let mut obs = env.reset(&kind.draw(seed, index)).map_err(refused)?;
    let mut rewards = Vec::new();
    for action in actions.as_slice()?.chunks_exact(ACTION_LEN) {
        let t = env.step(&action_of(action)?).map_err(refused)?;
        obs.extend_from_slice(&t.observation);
        rewards.push(t.reward);
    }
    let rows = rewards.len() + 1;
    let obs = Array2::from_shape_vec((rows, env.obs_dim()), obs).map_err(refused)?;
    Ok((obs.into_pyarray(py), PyArray1::from_vec(py, rewards)))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Env>()?;
    m.add_class::<VecEnv>()?;
    m.add_function(wrap_pyfunction!(reference_rollout, m)?)?;
    Ok(())
}
