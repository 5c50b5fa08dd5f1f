//! Shipped models and blobs from Python: `Policy` (an onboard weight blob flown by the onboard
//! crate's f32 or int8 kernels), `open_model` (a `models/NAME` folder checked against its card
//! as the command line checks it: every file's CRC-32C, the f32 blob equal to the actor) and
//! `fly_sil` (a blob in the software-in-the-loop guidance loop against the nominal or the
//! dispersed plant, as `ground model sil`).

use std::collections::BTreeMap;
use std::path::PathBuf;

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use rayon::prelude::*;

use firmware_sim::{
    fly_observed, with_flight_problem, with_spatial_flight_problem, Controller, Dispersions, FlightSetup,
    FlightSummary, ScenarioOf,
};
use ground_core::env::EnvConfig;
use ground_core::model_files::{blob_file, read_sealed_card, verify_model_files, Aids, ACTOR_FILE, ONNX_FILE};
use onboard::features::{ACTION3_LEN, ACTION_LEN};
use onboard::guidance::{Actor, Aided, Guide};
use onboard::lookahead::LookaheadSettings;
use onboard::terminal::{TerminalSettings, MAX_CYCLES};
use shared::blob::{AlignedBlob, FeatureLayout, ProblemKind, Quantization};

use crate::{refused, spatial_scenario_family};

fn problem_name(kind: ProblemKind) -> &'static str {
    match kind {
        ProblemKind::Transfer => "transfer",
        ProblemKind::Rendezvous => "rendezvous",
    }
}

/// An onboard weight blob (f32 or int8), checked as flight software checks it at load (magic,
/// version, CRC-32, problem, shape), flown by the onboard kernels: a planar network, or a
/// three-dimensional one (15 or 30 features, 4 actions).
#[pyclass(module = "lowthrust._lowthrust")]
pub struct Policy {
    blob: AlignedBlob,
    kind: ProblemKind,
    features: FeatureLayout,
    quantization: Quantization,
    /// The mission the blob flies (fingerprint 0: the thesis's units and cycle, any family).
    mission: shared::blob::BlobMission,
}

/// The actions of `inputs` (rows of `N`) by the onboard controller of `blob`, `OUT` per row.
fn actions_of<const N: usize, const OUT: usize>(controller: &Controller<'_, N, OUT>, inputs: &[f32]) -> Vec<f32> {
    inputs
        .par_chunks_exact(N)
        .flat_map_iter(|x| {
            let x: &[f32; N] = x.try_into().unwrap_or(&[0.0; N]);
            controller.act(x)
        })
        .collect()
}

impl Policy {
    fn load(bytes: &[u8]) -> PyResult<Self> {
        let decoded = shared::blob::decode(bytes).map_err(|e| refused(format!("blob refused: {e:?}")))?;
        let (kind, features, quantization, mission) =
            (decoded.kind, decoded.features, decoded.quantization, decoded.mission);
        let blob = AlignedBlob::new(bytes);
        // The loader flight software runs: a blob it refuses is refused here too.
        if let Some(e) = firmware_sim::load_refusal(blob.bytes(), features) {
            return Err(refused(format!("blob refused by the onboard loader: {e:?}")));
        }
        Ok(Self {
            blob,
            kind,
            features,
            quantization,
            mission,
        })
    }
}

#[pymethods]
impl Policy {
    /// `Policy(blob)`: the blob's bytes.
    #[new]
    fn new(blob: &[u8]) -> PyResult<Self> {
        Self::load(blob)
    }

    /// The blob in the file at `path`.
    #[staticmethod]
    fn from_file(path: PathBuf) -> PyResult<Self> {
        let bytes = std::fs::read(&path).map_err(|e| refused(format!("{}: {e}", path.display())))?;
        Self::load(&bytes)
    }

    /// The deterministic actions of observations `(n, features)` float32: `(n, actions)` float32
    /// in [-1, 1] (3 in the plane, 4 in three dimensions), computed by the onboard kernels as in
    /// flight.
    fn act<'py>(
        &self,
        py: Python<'py>,
        observations: PyReadonlyArray2<'py, f32>,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let [n, width] = observations.shape() else {
            return Err(refused("observations must be (n, features)"));
        };
        let (n, width) = (*n, *width);
        let inputs = observations.as_slice()?;
        if !inputs.iter().all(|x| x.is_finite()) {
            return Err(refused("an observation has a NaN or infinite component"));
        }
        if width != self.features.len() {
            return Err(refused(format!(
                "observations of {width} features, this {} network takes {}",
                problem_name(self.kind),
                self.features.len()
            )));
        }
        let blob = self.blob.bytes();
        let actions = if self.features.is_spatial() {
            with_spatial_flight_problem!(self.kind, N, P => {
                let controller = Controller::<N, ACTION3_LEN>::load::<P>(blob);
                py.detach(|| actions_of(&controller, inputs))
            })
        } else {
            with_flight_problem!(self.kind, N, P => {
                let controller = Controller::<N>::load::<P>(blob);
                py.detach(|| actions_of(&controller, inputs))
            })
        };
        Ok(Array2::from_shape_vec((n, self.features.actions()), actions)
            .map_err(refused)?
            .into_pyarray(py))
    }

    /// `"transfer"` or `"rendezvous"`.
    #[getter]
    fn problem(&self) -> &'static str {
        problem_name(self.kind)
    }

    /// Network inputs (10 or 22 planar features, 15 or 30 in three dimensions).
    #[getter]
    fn obs_dim(&self) -> usize {
        self.features.len()
    }

    /// Action components (3 in the plane, 4 in three dimensions).
    #[getter]
    fn act_dim(&self) -> usize {
        self.features.actions()
    }

    /// `"f32"` or `"int8"`.
    #[getter]
    fn quantization(&self) -> &'static str {
        match self.quantization {
            Quantization::F32 => "f32",
            Quantization::Int8 => "int8",
        }
    }

    /// The blob's bytes.
    #[getter]
    fn blob<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, self.blob.bytes())
    }

    /// The mission the blob carries, as flight software reads it: `cycle` (t*; 0 for a count
    /// of cycles), `length_unit_m`, `time_unit_s`, `family` (the fingerprint; 0 for a blob made
    /// before blobs carried their mission: the thesis's units and cycle, any family).
    #[getter]
    fn mission<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        d.set_item("cycle", self.mission.cycle)?;
        d.set_item("length_unit_m", self.mission.length_unit_m)?;
        d.set_item("time_unit_s", self.mission.time_unit_s)?;
        d.set_item("family", self.mission.family)?;
        Ok(d)
    }
}

/// Opens the model folder `dir` (`models/NAME`): its card.json is read, every file it lists
/// must have the CRC-32C it records, the actor and both blobs must be listed, and the f32 blob
/// must hold exactly the actor's weights. Returns a dict: `name` (the card's), `scenario` (its
/// family: a preset's name or the family's table as TOML text), `env_config` (its `[env]` as
/// TOML text: spacecraft, reward), `sil_dispersions` (its `[sil.dispersions]` as TOML text, the
/// dispersions its card's SIL flew; empty when the config has none), `sil_aids` (the onboard aids
/// its card's SIL flew: its `[sil]` tables `lookahead` and `terminal` as TOML text, for
/// `fly_sil`'s `aids`; empty when it flies none), `card` (card.json as a dict), `f32` and `int8` (`Policy`),
/// `files` (paths of the actor, the blobs and, when the folder has it, `onnx`).
#[pyfunction]
fn open_model<'py>(py: Python<'py>, dir: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let card_path = dir.join("card.json");
    let text = std::fs::read_to_string(&card_path).map_err(|e| refused(format!("{}: {e}", card_path.display())))?;
    let card = read_sealed_card(&card_path, &text).map_err(refused)?;
    let bad = |what: &str| refused(format!("{}: {what}", card_path.display()));
    let name = card["scenario"].as_str().ok_or_else(|| bad("no scenario"))?;
    // The family and the environment the model flies, from the card's config: a preset's name,
    // or the family's table as TOML text (what `Env` takes either way).
    let config: toml::Table = card["config"]
        .as_str()
        .ok_or_else(|| bad("no config"))
        .and_then(|c| toml::from_str(c).map_err(|e| bad(&format!("its config does not read: {e}"))))?;
    let scenario = match config.get("scenario") {
        Some(toml::Value::String(preset)) => preset.clone(),
        Some(toml::Value::Table(table)) => toml::to_string(table).map_err(|e| bad(&e.to_string()))?,
        _ => return Err(bad("its config has no scenario")),
    };
    let family = spatial_scenario_family(&scenario)?;
    let kind = family.family.problem;
    let features = FeatureLayout::of(kind, family.as_planar().is_none());
    // A table of the config as TOML text, empty when the config has none.
    let table_text = |value: Option<&toml::Value>| match value {
        Some(toml::Value::Table(table)) => toml::to_string(table).map_err(|e| bad(&e.to_string())),
        _ => Ok(String::new()),
    };
    let env_config = table_text(config.get("env"))?;
    // The dispersions its SIL flew (`[sil.dispersions]`), for `fly_sil`'s `dispersions`.
    let sil_dispersions = table_text(config.get("sil").and_then(|sil| sil.get("dispersions")))?;
    // The aids its SIL flew (`[sil] lookahead`, `terminal`), for `fly_sil`'s `aids`.
    let mut aids = toml::Table::new();
    for name in ["lookahead", "terminal"] {
        if let Some(table) = config.get("sil").and_then(|sil| sil.get(name)) {
            aids.insert(name.into(), table.clone());
        }
    }
    let sil_aids = toml::to_string(&aids).map_err(|e| bad(&e.to_string()))?;
    let files: BTreeMap<String, String> =
        serde_json::from_value(card["files"].clone()).map_err(|e| bad(&format!("its files do not read: {e}")))?;
    let checked = py
        .detach(|| verify_model_files(&dir, features, &files))
        .map_err(refused)?;
    let d = PyDict::new(py);
    d.set_item("name", name)?;
    d.set_item("scenario", scenario)?;
    d.set_item("env_config", env_config)?;
    d.set_item("sil_dispersions", sil_dispersions)?;
    d.set_item("sil_aids", sil_aids)?;
    d.set_item("card", py.import("json")?.call_method1("loads", (text,))?)?;
    d.set_item("f32", Policy::load(&checked.f32_blob)?)?;
    d.set_item("int8", Policy::load(&checked.int8_blob)?)?;
    let paths = PyDict::new(py);
    paths.set_item("actor", dir.join(ACTOR_FILE))?;
    paths.set_item("f32", dir.join(blob_file(kind, Quantization::F32)))?;
    paths.set_item("int8", dir.join(blob_file(kind, Quantization::Int8)))?;
    if files.contains_key(ONNX_FILE) {
        paths.set_item("onnx", dir.join(ONNX_FILE))?;
    }
    d.set_item("files", paths)?;
    Ok(d)
}

/// How a SIL flight ended.
struct FlightEnd {
    dr: f64,
    dv: f64,
    mass: f64,
    reward: f64,
    faults: u32,
}

impl FlightEnd {
    /// The end of a flight of geometry `G`.
    fn of<G: firmware_sim::FlightGeometry>(
        flown: Result<FlightSummary<G>, firmware_sim::SilError>,
    ) -> Result<Self, String> {
        let summary = flown.map_err(|e| e.to_string())?;
        let res = summary.final_residuals.ok_or("no cycle flown")?;
        Ok(Self {
            dr: res.position,
            dv: res.velocity,
            mass: G::mass(&summary.final_state),
            reward: summary.total_reward,
            faults: summary.guidance_faults,
        })
    }
}

/// Flies scenarios `scenario(i)`, i in `0..episodes`, as problem `P` with `blob`'s controller
/// (safe mode when the blob is refused), flight i's dispersions drawn from `seed + i`, with the
/// onboard `aids` (rollout lookahead, then terminal targeting of the last cycles, each when
/// set): one implementation for both dimensions.
fn fly_flights<const N: usize, const OUT: usize, P>(
    blob: &[u8],
    scenario: impl Fn(u64) -> ScenarioOf<P, N> + Sync,
    setup: &FlightSetup,
    seed: u64,
    episodes: u64,
    aids: Aids,
) -> Vec<Result<FlightEnd, String>>
where
    P: firmware_sim::Problem<N> + Default,
    for<'b> Controller<'b, N, OUT>: Sync,
    for<'b, 'c> Aided<&'c Controller<'b, N, OUT>>: Guide<N, P::Target, P::Geometry>,
{
    let controller = Controller::<N, OUT>::load::<P>(blob);
    (0..episodes)
        .into_par_iter()
        .map(|i| {
            let flight_seed = seed.wrapping_add(i);
            // A refused blob flies safe mode, thrust off every cycle: no aid to fly.
            let network = matches!(controller, Controller::Network(_));
            let guide = Aided {
                actor: &controller,
                spacecraft: setup.spacecraft,
                lookahead: aids.lookahead.filter(|_| network),
                terminal: aids.terminal.filter(|_| network),
            };
            let flown = fly_observed(P::default(), &guide, &scenario(i), setup, flight_seed, |_| ());
            FlightEnd::of(flown)
        })
        .collect()
}

/// Flies `policy` in the SIL guidance loop on scenarios `0..episodes` of the stream `seed` of
/// the family `kind` (a preset's name, a mission file or table; flight i's dispersions drawn
/// from `seed + i`, as `ground model sil` does), against the nominal plant or (`dispersed`) the
/// typical dispersions: navigation noise, thrust magnitude and pointing errors, missed-thrust
/// events. An inclined family's blob flies the three-dimensional loop (its pointing error a
/// cone about the command). With `terminal_cycles` the last that many cycles (1 to 8) of each
/// flight are flown with terminal targeting (`onboard::terminal`) counting the family's cycles;
/// `aids` (the `[sil]` tables `lookahead` and `terminal` of a config as TOML text, `open_model`'s
/// `sil_aids`) flies the onboard aids they set instead, rollout lookahead (`onboard::lookahead`)
/// included, as the model's own SIL flew them. `env_config` (the `[env]` of a
/// config as TOML text, `open_model`'s `env_config`) sets the spacecraft, integrator and reward
/// weights, as the model's own SIL flew them; `dispersions` (a `[sil.dispersions]` table as TOML
/// text, `open_model`'s `sil_dispersions`) replaces the typical dispersions of a dispersed
/// flight. Returns per-flight arrays: `dr`, `dv` (terminal
/// residuals), `final_mass`, `total_reward`, `guidance_faults`, `completed`.
#[pyfunction]
#[pyo3(signature = (policy, kind, seed, episodes, dispersed=true, terminal_cycles=None, env_config=None, dispersions=None, aids=None))]
#[allow(clippy::too_many_arguments)] // the Python signature's keywords
fn fly_sil<'py>(
    py: Python<'py>,
    policy: &Policy,
    kind: &str,
    seed: u64,
    episodes: u64,
    dispersed: bool,
    terminal_cycles: Option<u32>,
    env_config: Option<&str>,
    dispersions: Option<&str>,
    aids: Option<&str>,
) -> PyResult<Bound<'py, PyDict>> {
    let family = spatial_scenario_family(kind)?;
    let kind = family.family;
    let env = match env_config {
        None => EnvConfig::default(),
        Some(text) => toml::from_str(text).map_err(|e| refused(format!("env config: {e}")))?,
    };
    let env = EnvConfig { body: kind.body, ..env };
    let cycle = kind.fixed_cycle();
    let given = match (terminal_cycles, aids) {
        (Some(_), Some(_)) => return Err(refused("give terminal_cycles or aids, not both")),
        (None, Some(text)) => toml::from_str(text).map_err(|e| refused(format!("aids: {e}")))?,
        (cycles, None) => Aids {
            lookahead: None,
            terminal: cycles.map(|cycles| TerminalSettings {
                cycles,
                ..TerminalSettings::default()
            }),
        },
    };
    let flown_aids = if given.lookahead.is_none() && given.terminal.is_none() {
        given
    } else {
        // The aids count the family's cycles and propagate as its environment does.
        let cycle = cycle.ok_or_else(|| {
            refused("the onboard aids count cycles of one length; this family cuts flights of different lengths into a count of cycles each")
        })?;
        let tolerances = env.integrator.tolerances();
        let aids = Aids {
            lookahead: given.lookahead.map(|l| LookaheadSettings { cycle, tolerances, ..l }),
            terminal: given.terminal.map(|t| TerminalSettings { cycle, tolerances, ..t }),
        };
        if aids.terminal.is_some_and(|t| t.validate().is_err()) {
            let cycles = aids.terminal.map_or(0, |t| t.cycles);
            return Err(refused(match terminal_cycles {
                Some(_) => format!("terminal_cycles must be 1 to {MAX_CYCLES}, not {cycles}"),
                None => format!("aids: terminal: cycles must be 1 to {MAX_CYCLES} and iterations 1 to 64"),
            }));
        }
        if let Some(Err(e)) = aids.lookahead.map(|l| l.validate()) {
            return Err(refused(format!("aids: lookahead: {e}")));
        }
        aids
    };
    if kind.problem != policy.kind || family.as_planar().is_none() != policy.features.is_spatial() {
        return Err(refused(format!(
            "a {} blob ({:?}) cannot fly {} scenarios",
            policy.problem(),
            policy.features,
            family.label()
        )));
    }
    if let Some(why) = ground_core::mission::blob_refusal(&family, &policy.mission) {
        return Err(refused(why));
    }
    let spacecraft = env
        .canonical_spacecraft()
        .map_err(|e| refused(format!("spacecraft: {e}")))?;
    let setup = FlightSetup {
        spacecraft,
        tolerances: env.integrator.tolerances(),
        weights: env.reward.weights(),
        dispersions: match (dispersed, dispersions.filter(|text| !text.trim().is_empty())) {
            (false, _) => Dispersions::NONE,
            (true, None) => Dispersions::typical_in(&kind.body.units()),
            (true, Some(text)) => {
                let given: Dispersions = toml::from_str(text).map_err(|e| refused(format!("dispersions: {e}")))?;
                given.validate().map_err(|e| refused(format!("dispersions: {e:?}")))?;
                given
            }
        },
        time_unit_s: kind.body.units().time_s,
    };
    let blob = policy.blob.bytes();
    let flights = if family.as_planar().is_none() {
        with_spatial_flight_problem!(kind.problem, N, P => py.detach(|| {
            fly_flights::<N, ACTION3_LEN, P>(blob, |i| family.draw(seed, i), &setup, seed, episodes, flown_aids)
        }))
    } else {
        with_flight_problem!(kind.problem, N, P => py.detach(|| {
            fly_flights::<N, ACTION_LEN, P>(blob, |i| kind.draw(seed, i), &setup, seed, episodes, flown_aids)
        }))
    };
    let completed: Vec<bool> = flights.iter().map(Result::is_ok).collect();
    let value =
        |f: fn(&FlightEnd) -> f64| -> Vec<f64> { flights.iter().map(|r| r.as_ref().map_or(f64::NAN, f)).collect() };
    let d = PyDict::new(py);
    d.set_item("dr", PyArray1::from_vec(py, value(|r| r.dr)))?;
    d.set_item("dv", PyArray1::from_vec(py, value(|r| r.dv)))?;
    d.set_item("final_mass", PyArray1::from_vec(py, value(|r| r.mass)))?;
    d.set_item("total_reward", PyArray1::from_vec(py, value(|r| r.reward)))?;
    d.set_item(
        "guidance_faults",
        PyArray1::from_vec(py, value(|r| f64::from(r.faults))),
    )?;
    d.set_item("completed", PyArray1::from_vec(py, completed))?;
    Ok(d)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Policy>()?;
    m.add_function(wrap_pyfunction!(open_model, m)?)?;
    m.add_function(wrap_pyfunction!(fly_sil, m)?)?;
    Ok(())
}
