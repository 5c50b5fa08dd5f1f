//! Pretraining (docs/spec.md section 8): the demonstrations of the config's dataset fill the
//! replay buffer, then N_pt updates with periodic evaluations; the best model is kept.
//!
//! ```text
//! RUN/pretrain/{best,last}.safetensors  the best (by evaluation) and latest learner state
//! RUN/pretrain/replay.ltrb              the demonstration buffer handed to RL
//! RUN/pretrain/{eval,updates}.csv       evaluation rows and loss averages, plus SVG plots
//! ```

use std::path::{Path, PathBuf};

use crate::config::ExperimentConfig;
use crate::error::ExperimentError;
use crate::phase::{load_state, new_agent, Phase, PhaseSummary};
use crate::run_folder::{prepare_run, save_replay};
use crate::sac::replay::{sampler, ReplayBuffer, Transition};
use crate::with_flown_problem;
use ground_core::demo::{default_tolerances, DemoGeometry, Demonstrations};
use ground_core::env::{ActionOf, Geometry, MdpEnv, Problem};

/// `ground train pretrain`: demonstrations into the buffer, N_pt updates, evaluations every
/// `pretrain.eval_every` updates, the best model kept (docs/spec.md section 8). An inclined
/// family learns from a three-dimensional dataset (docs/spec.md section 7.1).
pub fn pretrain(config: &ExperimentConfig, config_dir: &Path, run: &Path) -> Result<PhaseSummary, ExperimentError> {
    with_flown_problem!(config, P => pretrain_for::<P>(config, config_dir, run))
}

/// The demonstration tuples of problem `P`.
pub type ProblemDemonstrations<P> = Demonstrations<<P as Problem>::Obs, ActionOf<<P as Problem>::Geometry>>;

/// The demonstration tuples of the config's dataset (refused when the dataset is of another
/// problem, central body, guidance cycle, arrival margin, spacecraft or dimension), with the dataset file
/// and its record count.
pub fn load_demonstrations<P: Problem>(
    config: &ExperimentConfig,
    config_dir: &Path,
) -> Result<(ProblemDemonstrations<P>, PathBuf, usize), ExperimentError>
where
    P::Geometry: DemoGeometry,
{
    let file = config.dataset_file(config_dir)?;
    let dataset =
        P::Geometry::load_dataset(&file).map_err(|e| ExperimentError::Dataset(format!("{}: {e}", file.display())))?;
    let (theirs, ours) = (&dataset.family.family, &config.family.family);
    // Another range of orbits is still the same physics; another body or cycle is not.
    if theirs.problem != P::KIND || theirs.body != ours.body || theirs.cycle != ours.cycle {
        return Err(ExperimentError::Mismatch(format!(
            "dataset {} holds {} trajectories, the config is for {}",
            file.display(),
            dataset.family.label(),
            config.family.label()
        )));
    }
    // Relabels are solved with the config's margin: demonstrations of another would teach two
    // arrival times.
    if dataset.arrival_margin != config.generate.arrival_margin {
        return Err(ExperimentError::Mismatch(format!(
            "dataset {} was solved to arrive {} steps early, the config asks for generate.arrival_margin = {}",
            file.display(),
            dataset.arrival_margin,
            config.generate.arrival_margin
        )));
    }
    // Optima of another spacecraft are not this learner's: their cycles would not re-integrate.
    let spacecraft = &config.env.spacecraft;
    let canonical = config
        .env
        .canonical_spacecraft()
        .map_err(|e| ExperimentError::Mismatch(format!("env.spacecraft: {e}")))?;
    ground_core::generate::check_spacecraft(
        dataset.spacecraft,
        &canonical,
        || format!("dataset {} holds records", file.display()),
        format!(
            "solve it for the config's [env.spacecraft] (ground data generate --thrust-n {} --isp-s {} --mass-kg {})",
            spacecraft.max_thrust_n, spacecraft.isp_s, spacecraft.initial_mass_kg
        ),
    )
    .map_err(|e| ExperimentError::Mismatch(e.to_string()))?;
    let demos = P::Geometry::tuples::<P>(
        &dataset.records,
        &config.env,
        config.pretrain.records,
        &default_tolerances(),
    );
    Ok((demos, file, dataset.records.len()))
}

/// The demonstration tuples of the config's dataset as replay transitions.
pub fn demonstration_buffer<P: Problem>(
    config: &ExperimentConfig,
    config_dir: &Path,
) -> Result<(ReplayBuffer, usize), ExperimentError>
where
    P::Geometry: DemoGeometry,
{
    let (demos, file, records) = load_demonstrations::<P>(config, config_dir)?;
    if demos.transitions.is_empty() {
        return Err(ExperimentError::Dataset(format!(
            "{} gave no demonstration tuples ({} records, {} failed, {} filtered out)",
            file.display(),
            records,
            demos.failed.len(),
            demos.filtered_out
        )));
    }
    let mut buffer = ReplayBuffer::new(
        P::OBS,
        P::Geometry::ACT,
        config.sac.replay_capacity.max(demos.transitions.len()),
    );
    push_demonstrations(&mut buffer, &demos.transitions);
    Ok((buffer, demos.used))
}

/// Appends demonstration tuples to a replay buffer, flagged as demonstrations.
pub fn push_demonstrations<O: AsRef<[f32]>, A: AsRef<[f32]>>(
    buffer: &mut ReplayBuffer,
    transitions: &[ground_core::demo::Transition<O, A>],
) {
    for t in transitions {
        buffer.push(&Transition {
            obs: t.observation.as_ref(),
            action: t.action.as_ref(),
            reward: t.reward as f32,
            next_obs: t.next_observation.as_ref(),
            done: t.done,
            demonstration: true,
        });
    }
}

fn pretrain_for<P: Problem>(
    config: &ExperimentConfig,
    config_dir: &Path,
    run: &Path,
) -> Result<PhaseSummary, ExperimentError>
where
    P::Geometry: DemoGeometry,
{
    let device = config.device()?;
    let (buffer, used) = demonstration_buffer::<P>(config, config_dir)?;
    prepare_run(config, run)?;
    let dir = run.join("pretrain");
    let mut agent = new_agent(config, true, P::OBS, device);
    let mut rng = sampler(config.seeds.train);
    let state = load_state(&dir.join("state.json"))?.unwrap_or_default();
    if state.updates > 0 {
        agent.load(&dir.join("last.safetensors"))?;
        rng.set_word_pos(state.sampler_word_pos);
    }
    let total = config.pretrain.updates;
    let mut phase = Phase::new(dir.clone(), config, state, total, "pretrain");
    phase.bar.set_position(phase.state.updates);
    // A finished phase asked for more updates continues; asked for the same, it only reports.
    if phase.state.updates < total || phase.state.evaluations.is_empty() {
        // Evaluate the untrained policy once, so the curve starts at update 0.
        if phase.state.evaluations.is_empty() {
            let row = phase.evaluate::<MdpEnv<P>>(&agent, 0)?;
            phase.state.best = Some(row);
            agent.save(&dir.join("best.safetensors"))?;
        }
        while phase.state.updates < total {
            let stats = agent.update(&buffer.sample(config.sac.batch_size, &mut rng));
            phase.record_update(0, &stats);
            if phase.state.updates.is_multiple_of(config.pretrain.eval_every) || phase.state.updates == total {
                let row = phase.evaluate::<MdpEnv<P>>(&agent, 0)?;
                if phase.improves(&row) {
                    phase.state.best = Some(row);
                    agent.save(&dir.join("best.safetensors"))?;
                }
                phase.checkpoint(&agent, None, &rng)?;
            }
        }
        save_replay(&dir.join("replay.ltrb"), &buffer)?;
        phase.checkpoint(&agent, None, &rng)?;
    }
    phase.bar.finish();
    Ok(PhaseSummary {
        folder: dir,
        updates: phase.state.updates,
        env_steps: 0,
        seconds: phase.state.seconds,
        best: phase.state.best,
        demonstration_records: used,
        demonstration_tuples: buffer.demonstration_count(),
    })
}
