//! From a checkpoint to flight: `ground model export` blobs against the tch actor, and the SIL loop
//! against the ground environment.

use std::path::PathBuf;

use firmware_sim::Dispersions;
use ground_core::env::batch::{draw_scenarios, evaluate, EpisodeOutcome};
use ground_core::env::{MdpEnv, Planar, Rendezvous, Transfer};
use learn::config::ExperimentConfig;
use learn::eval::{reused_optima, Optima};
use learn::export::{export, OnboardPolicy};
use learn::sac::agent::Sac;
use learn::sil::{fly_blob, sil_monte_carlo, SilFlights};
use onboard::policy::TransferPolicy;
use shared::blob::{FeatureLayout, ProblemKind, Quantization};

fn scratch_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lowthrust-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The onboard contract's network (10-256-256-3), small evaluation sets, no dataset: the
/// export calibrates on the states the policy visits.
fn config() -> ExperimentConfig {
    ExperimentConfig::from_toml(
        r#"
scenario = "transfer-circular"
[sac]
hidden = [256, 256]
[evaluate]
episodes = 24
optimality_gap_cases = 0
[sil]
episodes = 12
[compute]
threads = 1
"#,
    )
    .unwrap()
}

/// Features spread over what flight meets: radii 0.5-2 AU, speeds, mass, time to go.
fn features(k: usize) -> [f32; 10] {
    let u = |i: usize| ((k * 10 + i) as f32 * 0.618_034).fract();
    [
        0.5 + 1.5 * u(0),
        2.0 * u(1) - 1.0,
        2.0 * u(2) - 1.0,
        0.4 * u(3) - 0.2,
        0.6 + 0.8 * u(4),
        0.7 + 0.3 * u(5),
        1.0 + 0.5 * u(6),
        0.2 * u(7) - 0.1,
        0.7 + 0.4 * u(8),
        12.0 * u(9),
    ]
}

#[test]
fn exported_blobs_fly_the_trained_actor_and_sil_reproduces_the_environment() {
    let dir = scratch_dir("export-sil");
    let config = config();
    // A freshly initialised agent is a network like any other for the export.
    tch::manual_seed(5);
    let agent = Sac::new(config.sac.clone(), 10, 3, tch::Device::Cpu);
    let checkpoint = dir.join("agent.safetensors");
    agent.save(&checkpoint).unwrap();

    let report = export(&config, &dir, &checkpoint, &dir.join("export")).unwrap();
    assert_eq!(report.closed_loop_episodes, 24);
    assert_eq!(report.demonstration_states, 0);
    assert!(report.calibration_states > 1000 && report.held_out_states > 1000);

    // f32: the onboard network equals the tch actor's deterministic action within 1e-5, on
    // states of its own choosing (not the exporter's).
    let f32_bytes = std::fs::read(&report.f32.file).unwrap();
    let f32_policy = TransferPolicy::from_bytes(&f32_bytes, ProblemKind::Transfer).unwrap();
    assert_eq!(f32_policy.quantization(), Quantization::F32);
    let inputs: Vec<[f32; 10]> = (0..500).map(features).collect();
    let flat: Vec<f32> = inputs.iter().flatten().copied().collect();
    let tch_actions = agent.act(&flat, inputs.len());
    let mut worst_f32 = 0.0f32;
    let mut int8_errors = Vec::new();
    let int8_bytes = std::fs::read(&report.int8.file).unwrap();
    let int8_policy = TransferPolicy::from_bytes(&int8_bytes, ProblemKind::Transfer).unwrap();
    assert_eq!(int8_policy.quantization(), Quantization::Int8);
    for (x, want) in inputs.iter().zip(tch_actions.chunks_exact(3)) {
        for ((a, b), w) in f32_policy.forward(x).iter().zip(int8_policy.forward(x)).zip(want) {
            worst_f32 = worst_f32.max((a - w).abs());
            int8_errors.push((b - w).abs());
        }
    }
    assert!(worst_f32 <= 1e-5, "f32 blob vs tch actor: {worst_f32}");
    assert!(report.f32.action_error.max <= 1e-5);
    // int8 is an approximation, but a close one: median error well under 1 % of the range.
    int8_errors.sort_by(f32::total_cmp);
    let median = int8_errors[int8_errors.len() / 2];
    assert!(median < 0.02 && median > 0.0, "int8 median action error {median}");
    assert_eq!(report.int8.bytes, int8_bytes.len());
    assert!(int8_bytes.len() * 3 < f32_bytes.len());

    // SIL without dispersions flies exactly the ground environment's episodes (same onboard
    // network through the environment's own step).
    let scenarios = draw_scenarios(config.family.family, config.seeds.monte_carlo, 12);
    for bytes in [&f32_bytes, &int8_bytes] {
        let policy = OnboardPolicy::load(bytes, FeatureLayout::TransferPolar10).unwrap();
        let ground = evaluate::<MdpEnv<Transfer>, _>(
            &config.env,
            &scenarios,
            |o: &[f32; 10]| policy.action::<Planar>(o),
            false,
        )
        .unwrap();
        let (sil, faults, missed) = fly_blob(
            &config,
            bytes,
            &scenarios,
            &SilFlights::of(&config, &Dispersions::NONE, 0),
        )
        .unwrap();
        assert_eq!(faults, 0);
        assert!(
            missed.iter().all(|m| m.time == 0.0 && m.last_end.is_none()),
            "{missed:?}"
        );
        for (g, s) in ground.iter().zip(&sil) {
            assert!(g.completed && s.completed);
            assert_eq!(
                g.total_reward.to_bits(),
                s.total_reward.to_bits(),
                "episode {}",
                g.episode
            );
            assert_eq!(g.final_mass.to_bits(), s.final_mass.to_bits());
            assert_eq!(g.terminal, s.terminal);
        }
        // With dispersions the flights differ, and the dispersion is really flown.
        let (dispersed, _, missed) = fly_blob(
            &config,
            bytes,
            &scenarios,
            &SilFlights::of(&config, &Dispersions::TYPICAL, 0),
        )
        .unwrap();
        assert!(missed.iter().any(|m| m.time > 0.0));
        // A flight's last missed thrust is placed exactly when it met any.
        assert!(missed
            .iter()
            .all(|m| (m.time > 0.0) == m.last_end.is_some_and(|e| e > 0.0 && e <= 1.0)));
        assert!(dispersed.iter().zip(&sil).all(|(d, s)| d.final_mass != s.final_mass));
    }

    // The SIL Monte Carlo writes the evaluation's files, and a refused blob flies thrust off.
    let sil_dir = dir.join("sil");
    let sil = sil_monte_carlo(
        &config,
        &report.int8.file,
        &sil_dir,
        None,
        &config.sil.dispersions,
        Optima::NONE,
    )
    .unwrap();
    assert_eq!((sil.flights, sil.controller.as_str()), (12, "int8"));
    for file in [
        "sil.json",
        "mc.csv",
        "summary.json",
        "histograms.svg",
        "trajectories.svg",
    ] {
        assert!(sil_dir.join(file).is_file(), "sil/{file} missing");
    }

    // A draw's optimum does not depend on what flies it: the optima solved under the f32 blob's
    // nominal flights serve the int8 blob's dispersed ones on the same draws, row for row what
    // solving them again gives; optima of other draws, or none, are refused.
    let solved_dir = dir.join("gap-solved");
    let solved = sil_monte_carlo(
        &config,
        &report.f32.file,
        &solved_dir,
        Some(4),
        &Dispersions::NONE,
        Optima::Solve(Some(3)),
    )
    .unwrap();
    assert_eq!(solved.monte_carlo.gap.len(), 3);
    assert!(solved.monte_carlo.gap.iter().all(|row| row.optimal_converged));
    let fly_int8 = |folder: &str, optima: Optima| {
        sil_monte_carlo(
            &config,
            &report.int8.file,
            &dir.join(folder),
            Some(4),
            &config.sil.dispersions,
            optima,
        )
        .unwrap()
        .monte_carlo
    };
    let reused = fly_int8("gap-reused", reused_optima(&config, &solved_dir).unwrap());
    let fresh = fly_int8("gap-fresh", Optima::Solve(Some(3)));
    assert_eq!(format!("{:?}", reused.gap), format!("{:?}", fresh.gap));
    assert_eq!(reused.where_solved, fresh.where_solved);
    assert_eq!(reused.overspend, fresh.overspend);
    assert_eq!(reused.optima_key, solved.monte_carlo.optima_key);
    // The rows are the int8 flights' (dispersed), against the f32 flights' optima.
    for (row, before) in reused.gap.iter().zip(&solved.monte_carlo.gap) {
        assert_eq!(row.optimal_mass.to_bits(), before.optimal_mass.to_bits());
        assert_ne!(row.policy_mass.to_bits(), before.policy_mass.to_bits());
    }
    let mut other_draws = config.clone();
    other_draws.seeds.monte_carlo += 1;
    let refused = reused_optima(&other_draws, &solved_dir).unwrap_err().to_string();
    assert!(refused.contains("other draws"), "{refused}");
    let refused = reused_optima(&config, &sil_dir).unwrap_err().to_string();
    assert!(refused.contains("holds no optima"), "{refused}");

    let mut altered = int8_bytes.clone();
    altered[int8_bytes.len() / 2] ^= 0x10;
    let bad = dir.join("altered.blob");
    std::fs::write(&bad, &altered).unwrap();
    let refused = sil_monte_carlo(
        &config,
        &bad,
        &dir.join("sil-bad"),
        None,
        &config.sil.dispersions,
        Optima::NONE,
    )
    .unwrap();
    assert!(refused.controller.starts_with("safe mode"), "{}", refused.controller);
    assert_eq!(refused.monte_carlo.policy.final_mass.min, 1.0);
    // With lookahead: a good blob arrives no worse than alone on each nominal flight (the rollout
    // algorithm's guarantee, in the lookahead's own cost), a refused one still flies thrust off.
    let mut looking = config.clone();
    looking.sil.lookahead = Some(Default::default());
    let settings = looking.lookahead_settings().unwrap();
    let cost = |o: &EpisodeOutcome| {
        assert!(o.completed);
        settings.cost(&onboard::lookahead::Prediction {
            residuals: o.terminal,
            mass: o.final_mass,
            cost: 0.0,
        })
    };
    let (alone, _, _) = fly_blob(
        &config,
        &int8_bytes,
        &scenarios,
        &SilFlights::of(&config, &Dispersions::NONE, 0),
    )
    .unwrap();
    let (looked, _, _) = fly_blob(
        &looking,
        &int8_bytes,
        &scenarios,
        &SilFlights::of(&looking, &Dispersions::NONE, 0),
    )
    .unwrap();
    for (a, l) in alone.iter().zip(&looked) {
        assert!(
            cost(l) <= cost(a),
            "episode {}: {} against {}",
            a.episode,
            cost(l),
            cost(a)
        );
    }
    assert!(alone.iter().zip(&looked).any(|(a, l)| cost(l) < cost(a)));
    let refused = sil_monte_carlo(
        &looking,
        &bad,
        &dir.join("sil-bad-lookahead"),
        None,
        &Dispersions::TYPICAL,
        Optima::NONE,
    )
    .unwrap();
    assert_eq!(refused.monte_carlo.policy.final_mass.min, 1.0);
    assert!(refused.lookahead.is_some());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn rendezvous_blobs_fly_in_the_sil_as_in_the_environment_and_with_dispersions() {
    let dir = scratch_dir("export-sil-rendezvous");
    let config = ExperimentConfig::from_toml(
        r#"
scenario = "rendezvous-circular"
[sac]
hidden = [256, 256]
[evaluate]
episodes = 12
optimality_gap_cases = 0
[sil]
episodes = 8
[compute]
threads = 1
"#,
    )
    .unwrap();
    tch::manual_seed(6);
    let agent = Sac::new(config.sac.clone(), 22, 3, tch::Device::Cpu);
    let checkpoint = dir.join("agent.safetensors");
    agent.save(&checkpoint).unwrap();
    let report = export(&config, &dir, &checkpoint, &dir.join("export")).unwrap();
    let scenarios = draw_scenarios(config.family.family, config.seeds.monte_carlo, 8);
    for file in [&report.f32.file, &report.int8.file] {
        let bytes = std::fs::read(file).unwrap();
        // Without dispersions the SIL loop flies the environment's episodes bit for bit: the
        // body propagated onboard by the Kepler coast is the environment's body.
        let policy = OnboardPolicy::load(&bytes, FeatureLayout::RendezvousPolar22).unwrap();
        let ground = evaluate::<MdpEnv<Rendezvous>, _>(
            &config.env,
            &scenarios,
            |o: &[f32; 22]| policy.action::<Planar>(o),
            false,
        )
        .unwrap();
        let (sil, faults, missed) = fly_blob(
            &config,
            &bytes,
            &scenarios,
            &SilFlights::of(&config, &Dispersions::NONE, 0),
        )
        .unwrap();
        assert_eq!(faults, 0);
        assert!(
            missed.iter().all(|m| m.time == 0.0 && m.last_end.is_none()),
            "{missed:?}"
        );
        for (g, s) in ground.iter().zip(&sil) {
            assert!(g.completed && s.completed, "episode {}", g.episode);
            assert_eq!(
                g.total_reward.to_bits(),
                s.total_reward.to_bits(),
                "episode {}",
                g.episode
            );
            assert_eq!(g.final_mass.to_bits(), s.final_mass.to_bits());
            assert_eq!(g.terminal, s.terminal);
        }
        let (dispersed, _, missed) = fly_blob(
            &config,
            &bytes,
            &scenarios,
            &SilFlights::of(&config, &Dispersions::TYPICAL, 0),
        )
        .unwrap();
        assert!(missed.iter().any(|m| m.time > 0.0));
        // A flight's last missed thrust is placed exactly when it met any.
        assert!(missed
            .iter()
            .all(|m| (m.time > 0.0) == m.last_end.is_some_and(|e| e > 0.0 && e <= 1.0)));
        assert!(dispersed.iter().zip(&sil).all(|(d, s)| d.final_mass != s.final_mass));
    }
    // `ground model sil` flies the rendezvous blob, and refuses a transfer blob into safe mode.
    let sil = sil_monte_carlo(
        &config,
        &report.int8.file,
        &dir.join("sil"),
        None,
        &config.sil.dispersions,
        Optima::NONE,
    )
    .unwrap();
    assert_eq!((sil.flights, sil.controller.as_str()), (8, "int8"));
    assert_eq!(sil.monte_carlo.policy.completed, 8);
    let transfer_blob = dir.join("transfer.blob");
    let transfer = export(
        &self::config(),
        &dir,
        &{
            let a = Sac::new(self::config().sac.clone(), 10, 3, tch::Device::Cpu);
            let path = dir.join("transfer-agent.safetensors");
            a.save(&path).unwrap();
            path
        },
        &dir.join("transfer-export"),
    )
    .unwrap();
    std::fs::copy(&transfer.f32.file, &transfer_blob).unwrap();
    let refused = sil_monte_carlo(
        &config,
        &transfer_blob,
        &dir.join("sil-bad"),
        None,
        &config.sil.dispersions,
        Optima::NONE,
    )
    .unwrap();
    assert!(refused.controller.contains("Transfer"), "{}", refused.controller);
    std::fs::remove_dir_all(&dir).unwrap();
}
