//! The MDPs from Python: `Env` (one episode at a time) and `VecEnv` (many, stepped in
//! parallel in one call with the GIL released). Both are `ground_core::env::MdpEnv` itself, so
//! their transitions are the Rust environments' bit for bit.

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;

use ground_core::demo::DemoGeometry;
use ground_core::env::{ActionOf, Dimension, EnvConfig, Environment, FamilyOf, Geometry, MdpEnv, Problem, Step};
use ground_core::{with_problem, with_spatial_problem};
use shared::mission::SpatialFamily;

use crate::{refused, spatial_scenario_family};

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
    /// `[x, y, vx, vy, m]` in the plane, `[x, y, z, vx, vy, vz, m]` in three dimensions.
    state: Vec<f64>,
    mass: f64,
    base_reward: f64,
    terminal_term: f64,
}

/// One environment of any problem and geometry, with its family, behind one interface (the
/// feature and action counts are properties, not types, on this side).
trait AnyEnv: Send + Sync {
    /// Starts scenario `index` of the stream `seed`: the observation and the episode's steps.
    fn reset(&mut self, seed: u64, index: u64) -> Result<(Vec<f32>, u32), String>;
    fn step(&mut self, action: &[f32]) -> Result<Transition, String>;
    fn features(&self) -> Option<Vec<f64>>;
    fn observation(&self) -> Option<Vec<f32>>;
    fn state(&self) -> Option<Vec<f64>>;
    fn obs_dim(&self) -> usize;
    fn act_dim(&self) -> usize;
    fn is_done(&self) -> bool;
}

/// The MDP of problem `P` on the scenarios of `family`.
struct FamilyEnv<P: Problem> {
    family: FamilyOf<P::Geometry>,
    env: MdpEnv<P>,
}

impl<P: Problem> AnyEnv for FamilyEnv<P>
where
    P::Geometry: DemoGeometry,
    FamilyOf<P::Geometry>: Sync,
{
    fn reset(&mut self, seed: u64, index: u64) -> Result<(Vec<f32>, u32), String> {
        let scenario = P::Geometry::draw(&self.family, seed, index);
        let obs = Environment::reset(&mut self.env, &scenario).map_err(|e| e.to_string())?;
        Ok((obs.as_ref().to_vec(), P::Geometry::plan(&scenario).steps))
    }

    fn step(&mut self, action: &[f32]) -> Result<Transition, String> {
        let action = ActionOf::<P::Geometry>::try_from(action)
            .map_err(|_| format!("an action has {} components, not {}", P::Geometry::ACT, action.len()))?;
        let Step {
            observation,
            reward,
            done,
            info,
        } = Environment::step(&mut self.env, &action).map_err(|e| e.to_string())?;
        Ok(Transition {
            observation: observation.as_ref().to_vec(),
            features: self.env.features().map_or_else(Vec::new, |f| f.as_ref().to_vec()),
            reward,
            done,
            dr: info.residuals.position,
            dv: info.residuals.velocity,
            throttle: info.throttle,
            state: P::Geometry::state_numbers(&info.state),
            mass: P::Geometry::mass(&info.state),
            base_reward: info.base_reward,
            terminal_term: info.terminal_term,
        })
    }

    fn features(&self) -> Option<Vec<f64>> {
        MdpEnv::features(&self.env).map(|f| f.as_ref().to_vec())
    }

    fn observation(&self) -> Option<Vec<f32>> {
        Environment::observation(&self.env).map(|o| o.as_ref().to_vec())
    }

    fn state(&self) -> Option<Vec<f64>> {
        Environment::state(&self.env).map(|s| P::Geometry::state_numbers(&s))
    }

    fn obs_dim(&self) -> usize {
        P::OBS
    }

    fn act_dim(&self) -> usize {
        P::Geometry::ACT
    }

    fn is_done(&self) -> bool {
        Environment::is_done(&self.env)
    }
}

/// A new environment of `family`'s problem (planar, or three-dimensional for an inclined
/// family), with the `[env]` settings of a config (TOML text; none: the defaults), its
/// spacecraft in the family's units.
fn new_env(family: &SpatialFamily, config: &EnvConfig) -> PyResult<Box<dyn AnyEnv>> {
    let config = EnvConfig {
        body: family.family.body,
        ..*config
    };
    match family.as_planar() {
        Some(planar) => with_problem!(planar.problem, P => MdpEnv::<P>::new(&config)
            .map(|env| Box::new(FamilyEnv::<P> { family: planar, env }) as Box<dyn AnyEnv>)),
        None => with_spatial_problem!(family.family.problem, P => MdpEnv::<P>::new(&config)
            .map(|env| Box::new(FamilyEnv::<P> { family: *family, env }) as Box<dyn AnyEnv>)),
    }
    .map_err(refused)
}

fn env_config(text: Option<&str>) -> PyResult<EnvConfig> {
    match text {
        None => Ok(EnvConfig::default()),
        Some(text) => toml::from_str(text).map_err(|e| refused(format!("env config: {e}"))),
    }
}

/// An action's components, all finite (their count is the environment's to check).
fn finite_action(action: &[f32]) -> PyResult<&[f32]> {
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
        let kind = spatial_scenario_family(kind)?;
        let config = self::env_config(env_config)?;
        Ok(Self {
            env: new_env(&kind, &config)?,
            steps: 0,
        })
    }

    /// Starts scenario `index` of the stream `seed`; returns the observation (float32).
    fn reset<'py>(&mut self, py: Python<'py>, seed: u64, index: u64) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let (obs, steps) = self.env.reset(seed, index).map_err(refused)?;
        self.steps = steps;
        Ok(PyArray1::from_vec(py, obs))
    }

    /// One step under `action` (`act_dim` float32 in [-1, 1]: throttle and a direction, polar
    /// in the plane, RTN in three dimensions; outside is clamped): returns `(observation, reward,
    /// done, info)`, info with the features (float64), the residuals `dr`, `dv`, the throttle
    /// flown, the state (`[x, y, vx, vy, m]`, in three dimensions `[x, y, z, vx, vy, vz, m]`)
    /// and the reward's parts.
    fn step<'py>(&mut self, py: Python<'py>, action: PyReadonlyArray1<'py, f32>) -> PyResult<StepResult<'py>> {
        let t = self.env.step(finite_action(action.as_slice()?)?).map_err(refused)?;
        let info = PyDict::new(py);
        info.set_item("features", PyArray1::from_vec(py, t.features))?;
        info.set_item("dr", t.dr)?;
        info.set_item("dv", t.dv)?;
        info.set_item("throttle", t.throttle)?;
        info.set_item("mass", t.mass)?;
        info.set_item("state", PyArray1::from_vec(py, t.state))?;
        info.set_item("base_reward", t.base_reward)?;
        info.set_item("terminal_term", t.terminal_term)?;
        Ok((PyArray1::from_vec(py, t.observation), t.reward, t.done, info))
    }

    /// Number of observation features (10 transfer, 22 rendezvous; 15 and 30 in three
    /// dimensions).
    #[getter]
    fn obs_dim(&self) -> usize {
        self.env.obs_dim()
    }

    /// Number of action components (3 in the plane, 4 in three dimensions).
    #[getter]
    fn act_dim(&self) -> usize {
        self.env.act_dim()
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

    /// The current state `[x, y, vx, vy, m]` (in three dimensions `[x, y, z, vx, vy, vz, m]`;
    /// AU, AU/t*, m0; None before the first reset).
    #[getter]
    fn state<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.env.state().map(|s| PyArray1::from_vec(py, s))
    }
}

/// `num_envs` episodes of one scenario distribution stepped together: one call steps every
/// episode, in parallel in Rust with the GIL released. No autoreset: the Python wrapper resets
/// finished episodes (`reset` with a mask).
#[pyclass(module = "lowthrust._lowthrust")]
pub struct VecEnv {
    envs: Vec<Box<dyn AnyEnv>>,
    obs_dim: usize,
    act_dim: usize,
}

#[pymethods]
impl VecEnv {
    /// `VecEnv(kind, num_envs, env_config=None)`, as `Env`.
    #[new]
    #[pyo3(signature = (kind, num_envs, env_config=None))]
    fn new(kind: &str, num_envs: usize, env_config: Option<&str>) -> PyResult<Self> {
        let kind = spatial_scenario_family(kind)?;
        if num_envs == 0 {
            return Err(refused("num_envs must be at least 1"));
        }
        let config = self::env_config(env_config)?;
        let envs = (0..num_envs)
            .map(|_| new_env(&kind, &config))
            .collect::<PyResult<Vec<_>>>()?;
        let (obs_dim, act_dim) = (envs[0].obs_dim(), envs[0].act_dim());
        Ok(Self { envs, obs_dim, act_dim })
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
                            env.reset(seed, index).map(|(obs, _)| obs)
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

    /// Steps every episode under its row of `actions` `(num_envs, act_dim)` float32, or those where
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
        let act_dim = self.act_dim;
        if actions.shape() != [n, act_dim] {
            return Err(refused(format!(
                "actions of shape {:?} for {n} episodes of {act_dim} components",
                actions.shape()
            )));
        }
        let mask = match &mask {
            Some(m) if m.len() != n => return Err(refused(format!("a mask of {} for {n} episodes", m.len()))),
            Some(m) => m.as_slice()?.to_vec(),
            None => vec![true; n],
        };
        let actions = finite_action(actions.as_slice()?)?;
        let actions: Vec<&[f32]> = actions.chunks_exact(act_dim).collect();
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

    /// Number of action components.
    #[getter]
    fn act_dim(&self) -> usize {
        self.act_dim
    }
}

/// Scenario `index` of the stream `seed` flown under `actions` `(k, act_dim)` by the Rust
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
    let kind = spatial_scenario_family(kind)?;
    let mut env = new_env(&kind, &self::env_config(env_config)?)?;
    let act_dim = env.act_dim();
    if actions.shape()[1] != act_dim {
        return Err(refused(format!("actions must be (k, {act_dim})")));
    }
    let (mut obs, _) = env.reset(seed, index).map_err(refused)?;
    let mut rewards = Vec::new();
    for action in finite_action(actions.as_slice()?)?.chunks_exact(act_dim) {
        let t = env.step(action).map_err(refused)?;
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
