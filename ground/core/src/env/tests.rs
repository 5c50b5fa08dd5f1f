//! Environment tests: physics against Kepler and the rocket equation, rewards and features
//! against hand computations from the specification formulas (docs/spec.md) (not the onboard code), episode length,
//! determinism, errors.

use super::batch::{draw_scenarios, evaluate, evaluate_batched, run_episode, summarize, EvalError, Stats};
use super::*;
use onboard::features::FeatureError;
use shared::orbit::{OrbitElements, OrbitShape};
use shared::scenario::ScenarioKind;
use shared::units::{G0_M_S2, STEP, STEP_SECONDS};

const COAST: [f32; 3] = [-1.0, 0.0, 1.0];
const FULL_ALONG_TRACK: [f32; 3] = [1.0, 0.0, 1.0];

pub(super) fn transfer_scenario() -> Scenario {
    let initial = OrbitElements {
        shape: OrbitShape {
            a: 1.05,
            e: 0.1,
            omega: 0.3,
        },
        nu: 0.5,
    };
    let target = OrbitShape {
        a: 1.4,
        e: 0.2,
        omega: 1.0,
    };
    Scenario::transfer(initial, target)
}

pub(super) fn rendezvous_scenario() -> Scenario {
    Scenario {
        problem: ProblemKind::Rendezvous,
        target_nu0: 2.2,
        ..transfer_scenario()
    }
}

fn transfer_env() -> TransferEnv {
    TransferEnv::new(&EnvConfig::default()).unwrap()
}

fn rendezvous_env() -> RendezvousEnv {
    RendezvousEnv::new(&EnvConfig::default()).unwrap()
}

/// docs/spec.md section 2 polar quantities, written out.
fn polar(r: [f64; 2], v: [f64; 2]) -> (f64, f64, f64, f64) {
    let rr = (r[0] * r[0] + r[1] * r[1]).sqrt();
    (
        rr,
        r[1].atan2(r[0]),
        (r[0] * v[0] + r[1] * v[1]) / rr,
        (r[0] * v[1] - r[1] * v[0]) / rr,
    )
}

/// docs/spec.md section 5 target proxy at polar angle theta: (r_t, v_r_t, v_theta_t).
fn proxy(target: &OrbitShape, theta: f64) -> (f64, f64, f64) {
    let nu = theta - target.omega;
    let p = target.a * (1.0 - target.e * target.e);
    let k = (1.0 / p).sqrt();
    (
        p / (1.0 + target.e * nu.cos()),
        k * target.e * nu.sin(),
        k * (1.0 + target.e * nu.cos()),
    )
}

/// The printed reward of docs/spec.md section 5 with w_p = w_v = 0.2, w_u = 0.02.
fn spec_reward(dr: f64, dv: f64, u: f64) -> f64 {
    ((-0.2 * dr * dr).exp() - 1.0) + ((-0.2 * dv * dv).exp() - 1.0) - 0.02 * u
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * (1.0 + b.abs())
}

#[test]
fn zero_thrust_transfer_is_a_kepler_coast_with_the_spec_reward() {
    let scenario = transfer_scenario();
    let start = scenario.initial.cartesian();
    let mut env = transfer_env();
    env.reset(&scenario).unwrap();
    for k in 1..=scenario.steps {
        let step = env.step(&COAST).unwrap();
        let kepler = coast(&start, f64::from(k) * STEP).unwrap();
        let s = step.info.state;
        for i in 0..2 {
            assert!((s.r[i] - kepler.r[i]).abs() < 1e-11, "step {k}: {s:?} vs {kepler:?}");
            assert!((s.v[i] - kepler.v[i]).abs() < 1e-11, "step {k}: {s:?} vs {kepler:?}");
        }
        assert_eq!(s.m, 1.0);
        assert_eq!(step.info.throttle, 0.0);
        // Reward by hand from the specification formulas (docs/spec.md).
        let (r, theta, v_r, v_theta) = polar(s.r, s.v);
        let (r_t, v_r_t, v_theta_t) = proxy(&scenario.target, theta);
        let dr = (r_t - r).abs();
        let dv = ((v_r_t - v_r).powi(2) + (v_theta_t - v_theta).powi(2)).sqrt();
        assert!(close(step.info.residuals.position, dr, 1e-12));
        assert!(close(step.info.residuals.velocity, dv, 1e-12));
        assert!(close(step.reward, spec_reward(dr, dv, 0.0), 1e-12), "step {k}");
        assert_eq!(step.reward, step.info.base_reward);
        assert_eq!(step.done, k == scenario.steps);
    }
}

#[test]
fn zero_thrust_rendezvous_follows_kepler_for_both_bodies() {
    let scenario = rendezvous_scenario();
    let start = scenario.initial.cartesian();
    let body0 = scenario.target.cartesian_at(scenario.target_nu0);
    let mut env = rendezvous_env();
    env.reset(&scenario).unwrap();
    for k in 1..=scenario.steps {
        let step = env.step(&COAST).unwrap();
        let t = f64::from(k) * STEP;
        let (sc, body) = (coast(&start, t).unwrap(), coast(&body0, t).unwrap());
        let s = step.info.state;
        let dr = (body.r[0] - s.r[0]).hypot(body.r[1] - s.r[1]);
        let dv = (body.v[0] - s.v[0]).hypot(body.v[1] - s.v[1]);
        assert!((s.r[0] - sc.r[0]).abs() < 1e-11 && (s.v[1] - sc.v[1]).abs() < 1e-11);
        assert!(close(step.info.residuals.position, dr, 1e-12));
        assert!(close(step.info.residuals.velocity, dv, 1e-12));
        assert!(close(step.reward, spec_reward(dr, dv, 0.0), 1e-12), "step {k}");
    }
}

#[test]
fn full_thrust_mass_follows_the_rocket_equation() {
    // Constant thrust T at exhaust speed Isp g0: mdot = T / (Isp g0), so m(t) = m0 - mdot t,
    // computed here in SI from the spacecraft's own figures.
    let sc = Spacecraft::MSR_ERO;
    let mdot_kg_s = sc.max_thrust_n / (sc.isp_s * G0_M_S2);
    for scenario in [transfer_scenario(), rendezvous_scenario()] {
        let mut t_env = transfer_env();
        let mut r_env = rendezvous_env();
        let n = scenario.steps;
        let mut last = 0.0;
        for k in 1..=n {
            let step = match scenario.problem {
                ProblemKind::Transfer => {
                    if k == 1 {
                        t_env.reset(&scenario).unwrap();
                    }
                    t_env.step(&FULL_ALONG_TRACK).unwrap().info
                }
                ProblemKind::Rendezvous => {
                    if k == 1 {
                        r_env.reset(&scenario).unwrap();
                    }
                    r_env.step(&FULL_ALONG_TRACK).unwrap().info
                }
            };
            let expected_kg = sc.initial_mass_kg - mdot_kg_s * f64::from(k) * STEP_SECONDS;
            assert!(close(step.mass * sc.initial_mass_kg, expected_kg, 1e-9), "step {k}");
            assert_eq!(step.throttle, 1.0);
            last = step.mass;
        }
        // About 38 % of the wet mass left after 49 steps of full thrust (docs/spec.md section 1 figures).
        assert!(close(
            last,
            1.0 - 0.066_631_1 / 1.274_861_2 * f64::from(n) * 0.240_829_39,
            1e-6
        ));
    }
}

#[test]
fn transfer_observation_matches_the_spec_layout_field_by_field() {
    let scenario = transfer_scenario();
    let mut env = transfer_env();
    let mut obs = env.reset(&scenario).unwrap();
    let mut k = 0;
    loop {
        let s = env.state().unwrap();
        let (r, theta, v_r, v_theta) = polar(s.r, s.v);
        let (r_t, v_r_t, v_theta_t) = proxy(&scenario.target, theta);
        let t_tg = f64::from(scenario.steps - k) * STEP;
        let expect = [
            r,
            theta.cos(),
            theta.sin(),
            v_r,
            v_theta,
            s.m,
            r_t,
            v_r_t,
            v_theta_t,
            t_tg,
        ];
        assert_eq!(TransferEnv::OBS, 10);
        for (i, (got, want)) in obs.iter().zip(expect).enumerate() {
            assert!(
                (f64::from(*got) - want).abs() <= 2.0 * f64::from(f32::EPSILON) * want.abs().max(1.0),
                "step {k} feature {i}: {got} vs {want}"
            );
        }
        // Exactly the onboard narrowing of the f64 features.
        assert_eq!(obs, to_network_input(&env.features().unwrap()));
        if env.is_done() {
            assert_eq!(obs[9], 0.0);
            break;
        }
        obs = env.step(&[0.2, 0.6, -0.8]).unwrap().observation;
        k += 1;
    }
}

#[test]
fn rendezvous_observation_matches_the_spec_layout_field_by_field() {
    let scenario = rendezvous_scenario();
    let mut env = rendezvous_env();
    let mut obs = env.reset(&scenario).unwrap();
    let body0 = scenario.target.cartesian_at(scenario.target_nu0);
    let mut k = 0;
    loop {
        let s = env.state().unwrap();
        let b = coast(&body0, f64::from(k) * STEP).unwrap();
        let (ri, thi, _, _) = polar(s.r, s.v);
        let (rt, tht, _, _) = polar(b.r, b.v);
        let dr = [b.r[0] - s.r[0], b.r[1] - s.r[1]];
        let dv = [b.v[0] - s.v[0], b.v[1] - s.v[1]];
        let t_tg = f64::from(scenario.steps - k) * STEP;
        let expect = [
            ri,
            thi.cos(),
            thi.sin(),
            rt,
            tht.cos(),
            tht.sin(),
            s.r[0],
            s.r[1],
            s.v[0],
            s.v[1],
            b.r[0],
            b.r[1],
            b.v[0],
            b.v[1],
            dr[0],
            dr[1],
            dv[0],
            dv[1],
            dr[0].hypot(dr[1]),
            dv[0].hypot(dv[1]),
            t_tg,
            s.m,
        ];
        assert_eq!(RendezvousEnv::OBS, 22);
        for (i, (got, want)) in obs.iter().zip(expect).enumerate() {
            assert!(
                (f64::from(*got) - want).abs() <= 2.0 * f64::from(f32::EPSILON) * want.abs().max(1.0),
                "step {k} feature {i}: {got} vs {want}"
            );
        }
        assert_eq!(obs, to_network_input(&env.features().unwrap()));
        if env.is_done() {
            assert_eq!(obs[20], 0.0);
            break;
        }
        obs = env.step(&[0.0, -0.3, 0.9]).unwrap().observation;
        k += 1;
    }
}

#[test]
fn episodes_last_n_steps_per_the_time_of_flight_rule() {
    for kind in ScenarioKind::ALL {
        for index in 0..8 {
            let scenario = kind.draw(3, index);
            let p0 = 2.0 * std::f64::consts::PI * scenario.initial.shape.a.powf(1.5);
            let pf = 2.0 * std::f64::consts::PI * scenario.target.a.powf(1.5);
            let n = (p0.max(pf) / STEP).ceil() as u32;
            assert_eq!(scenario.steps, n, "{kind:?} {index}");
            assert!(f64::from(n) * STEP >= p0.max(pf) && f64::from(n - 1) * STEP < p0.max(pf));
            let outcome = match kind.problem() {
                ProblemKind::Transfer => run_episode(&mut transfer_env(), 0, &scenario, |_| COAST, true),
                ProblemKind::Rendezvous => run_episode(&mut rendezvous_env(), 0, &scenario, |_| COAST, true),
            };
            assert!(outcome.completed && outcome.error.is_none());
            assert_eq!(outcome.steps, n);
            assert_eq!(outcome.trajectory.unwrap().len(), n as usize + 1);
        }
    }
    // Stepping a finished episode is refused, and a reset starts over.
    let scenario = transfer_scenario();
    let mut env = transfer_env();
    let first = env.reset(&scenario).unwrap();
    assert_eq!(f64::from(first[9]), (f64::from(scenario.steps) * STEP) as f32 as f64);
    for k in 1..=scenario.steps {
        assert_eq!(env.step(&COAST).unwrap().done, k == scenario.steps);
    }
    assert!(env.is_done());
    assert_eq!(env.step(&COAST), Err(EnvError::EpisodeOver));
    assert_eq!(env.reset(&scenario).unwrap(), first);
    assert_eq!(env.steps_taken(), 0);
}

/// A deterministic policy that reads its observation (so trajectories depend on it).
fn wobble<const N: usize>(obs: &[f32; N]) -> [f32; 3] {
    let x: f32 = obs.iter().sum();
    [(3.0 * x).sin(), (5.0 * x).cos(), 0.5 + 0.5 * (7.0 * x).sin()]
}

#[test]
fn episodes_are_deterministic_per_seed_and_drivers_agree() {
    let config = EnvConfig::default();
    let scenarios = draw_scenarios(ScenarioKind::TransferHard, 11, 12);
    assert_eq!(scenarios, draw_scenarios(ScenarioKind::TransferHard, 11, 12));
    let sequential: Vec<_> = scenarios
        .iter()
        .enumerate()
        .map(|(i, s)| run_episode(&mut transfer_env(), i, s, wobble, true))
        .collect();
    let parallel = evaluate::<TransferEnv, _>(&config, &scenarios, wobble, true).unwrap();
    let batched =
        evaluate_batched::<TransferEnv, _>(&config, &scenarios, |o| o.iter().map(wobble).collect(), true).unwrap();
    assert_eq!(sequential, parallel);
    assert_eq!(sequential, batched);
    // Another seed gives other episodes.
    let other = evaluate::<TransferEnv, _>(
        &config,
        &draw_scenarios(ScenarioKind::TransferHard, 12, 12),
        wobble,
        false,
    )
    .unwrap();
    assert!(other
        .iter()
        .zip(&parallel)
        .all(|(a, b)| a.total_reward != b.total_reward));
    for o in &parallel {
        assert!(o.completed, "{o:?}");
        assert!(o.total_reward < 0.0 && o.final_mass < 1.0 && o.final_mass > 0.3);
    }
    // Same for the rendezvous, and reset_drawn is the draw.
    let scenarios = draw_scenarios(ScenarioKind::RendezvousHard, 5, 6);
    let a = evaluate::<RendezvousEnv, _>(&config, &scenarios, wobble, false).unwrap();
    let b =
        evaluate_batched::<RendezvousEnv, _>(&config, &scenarios, |o| o.iter().map(wobble).collect(), false).unwrap();
    assert_eq!(a, b);
    let mut env = rendezvous_env();
    assert_eq!(
        env.reset_drawn(ScenarioKind::RendezvousHard, 5, 3).unwrap(),
        rendezvous_env().reset(&scenarios[3]).unwrap()
    );
    let summary = summarize(&a);
    assert_eq!((summary.episodes, summary.completed), (6, 6));
    assert!(summary.total_reward.mean < 0.0);
}

#[test]
fn batched_policy_with_the_wrong_batch_size_is_refused() {
    let scenarios = draw_scenarios(ScenarioKind::TransferCircular, 1, 3);
    let err = evaluate_batched::<TransferEnv, _>(&EnvConfig::default(), &scenarios, |_| vec![COAST], false);
    assert_eq!(err, Err(EvalError::PolicyBatch { expected: 3, got: 1 }));
}

#[test]
fn non_finite_actions_coast_by_default_or_are_refused() {
    let scenario = transfer_scenario();
    let mut env = transfer_env();
    env.reset(&scenario).unwrap();
    let step = env.step(&[f32::NAN, 0.0, 1.0]).unwrap();
    assert!(step.info.non_finite_action);
    assert_eq!(step.info.throttle, 0.0);
    let mut coasting = transfer_env();
    coasting.reset(&scenario).unwrap();
    assert_eq!(coasting.step(&COAST).unwrap().observation, step.observation);

    let config = EnvConfig {
        non_finite_action: NonFiniteAction::Refuse,
        ..EnvConfig::default()
    };
    let mut strict = TransferEnv::new(&config).unwrap();
    let obs = strict.reset(&scenario).unwrap();
    assert_eq!(strict.step(&[0.0, f32::INFINITY, 1.0]), Err(EnvError::NonFiniteAction));
    assert_eq!(strict.observation(), Some(obs));
    assert_eq!(strict.steps_taken(), 0);
    // Out-of-range actions are clamped, tiny directions are thrust off.
    let mut a = transfer_env();
    a.reset(&scenario).unwrap();
    let mut b = transfer_env();
    b.reset(&scenario).unwrap();
    assert_eq!(
        a.step(&[7.0, 0.0, 3.0]).unwrap().observation,
        b.step(&FULL_ALONG_TRACK).unwrap().observation
    );
    assert_eq!(a.step(&[1.0, 1e-9, 0.0]).unwrap().info.throttle, 0.0);
}

#[test]
fn bad_inputs_give_typed_errors() {
    let mut env = transfer_env();
    assert_eq!(env.step(&COAST), Err(EnvError::NotReset));
    assert_eq!(env.observation(), None);
    assert_eq!(
        env.reset(&rendezvous_scenario()),
        Err(EnvError::WrongProblem {
            expected: ProblemKind::Transfer,
            found: ProblemKind::Rendezvous
        })
    );
    let mut bad = transfer_scenario();
    bad.target.e = 1.5;
    assert!(matches!(env.reset(&bad), Err(EnvError::Scenario(_))));
    bad = transfer_scenario();
    bad.steps = 0;
    assert!(matches!(env.reset(&bad), Err(EnvError::Scenario(_))));
    let s = transfer_scenario();
    let at_sun = SpacecraftState {
        r: [0.0, 0.0],
        v: [0.0, 1.0],
        m: 1.0,
    };
    assert!(matches!(
        env.reset_at(&s, &at_sun, 0),
        Err(EnvError::Features {
            step: 0,
            error: FeatureError::State(_)
        })
    ));
    let ok = SpacecraftState::from_cartesian(&s.initial.cartesian(), 1.0);
    assert_eq!(
        env.reset_at(&s, &ok, s.steps + 1),
        Err(EnvError::StepOutOfRange {
            step: s.steps + 1,
            steps: s.steps
        })
    );
    // A nearly empty tank: the step that would empty it is refused.
    let nearly_empty = SpacecraftState { m: 1e-3, ..ok };
    env.reset_at(&s, &nearly_empty, 0).unwrap();
    assert!(matches!(
        env.step(&FULL_ALONG_TRACK),
        Err(EnvError::Propagation {
            step: 0,
            error: PropagationError::MassDepleted
        })
    ));
    // Configs.
    let mut config = EnvConfig::default();
    config.spacecraft.isp_s = -1.0;
    assert!(matches!(TransferEnv::new(&config), Err(EnvError::Spacecraft(_))));
    let config = EnvConfig {
        terminal: TerminalAccuracy::TimeWeighted {
            position: 1.0,
            velocity: 1.0,
            horizon_steps: 0.0,
        },
        ..EnvConfig::default()
    };
    assert!(matches!(TransferEnv::new(&config), Err(EnvError::Config(_))));
    let mut config = EnvConfig::default();
    config.reward.throttle = f64::NAN;
    assert!(matches!(RendezvousEnv::new(&config), Err(EnvError::Config(_))));
    // A failing episode in a batch stops alone, with its error.
    let scenarios = [transfer_scenario(), bad];
    let out = evaluate::<TransferEnv, _>(&EnvConfig::default(), &scenarios, |_| COAST, false).unwrap();
    assert!(out[0].completed && !out[1].completed && matches!(out[1].error, Some(EnvError::Scenario(_))));
}

#[test]
fn terminal_accuracy_terms_weigh_the_residuals_as_time_runs_out() {
    let scenario = transfer_scenario();
    let fly = |terminal: TerminalAccuracy| {
        let config = EnvConfig {
            terminal,
            ..EnvConfig::default()
        };
        let mut env = TransferEnv::new(&config).unwrap();
        env.reset(&scenario).unwrap();
        (0..scenario.steps)
            .map(|_| env.step(&[0.0, 0.0, 1.0]).unwrap())
            .collect::<Vec<_>>()
    };
    let plain = fly(TerminalAccuracy::None);
    let penalty = fly(TerminalAccuracy::TerminalPenalty {
        position: 10.0,
        velocity: 5.0,
    });
    let weighted = fly(TerminalAccuracy::TimeWeighted {
        position: 10.0,
        velocity: 5.0,
        horizon_steps: 3.0,
    });
    let n = plain.len();
    for (k, ((p, t), w)) in plain.iter().zip(&penalty).zip(&weighted).enumerate() {
        // Same trajectory, same printed reward.
        assert_eq!(p.info.state, t.info.state);
        assert_eq!(p.info.base_reward, t.info.base_reward);
        assert_eq!(p.reward, p.info.base_reward);
        let lin = -(10.0 * p.info.residuals.position + 5.0 * p.info.residuals.velocity);
        let to_go = (n - 1 - k) as f64;
        let want = if k == n - 1 { lin } else { 0.0 };
        assert!(close(t.info.terminal_term, want, 1e-15) && close(t.reward, p.reward + want, 1e-15));
        assert!(
            close(w.info.terminal_term, lin * (-to_go / 3.0).exp(), 1e-15),
            "step {k}"
        );
    }
}

#[test]
fn config_reads_from_serde_with_defaults() {
    let config: EnvConfig = serde_json::from_str("{}").unwrap();
    assert_eq!(config, EnvConfig::default());
    assert_eq!(config.terminal, TerminalAccuracy::None);
    let json = r#"{"terminal": {"kind": "time-weighted", "position": 10.0, "velocity": 2.0, "horizon_steps": 3.0},
                   "non_finite_action": "refuse", "reward": {"throttle": 0.05}}"#;
    let config: EnvConfig = serde_json::from_str(json).unwrap();
    assert_eq!(
        config.terminal,
        TerminalAccuracy::TimeWeighted {
            position: 10.0,
            velocity: 2.0,
            horizon_steps: 3.0
        }
    );
    assert_eq!(config.non_finite_action, NonFiniteAction::Refuse);
    assert_eq!(config.reward.position, 0.2);
    assert_eq!(config.reward.throttle, 0.05);
    let back: EnvConfig = serde_json::from_str(&serde_json::to_string(&config).unwrap()).unwrap();
    assert_eq!(back, config);
    let p: TerminalAccuracy =
        serde_json::from_str(r#"{"kind": "terminal-penalty", "position": 1.0, "velocity": 1.0}"#).unwrap();
    assert_eq!(
        p,
        TerminalAccuracy::TerminalPenalty {
            position: 1.0,
            velocity: 1.0
        }
    );
    assert!(serde_json::from_str::<EnvConfig>(r#"{"terminal": {"kind": "quadratic"}}"#).is_err());
    assert!(serde_json::from_str::<EnvConfig>(r#"{"rewards": {}}"#).is_err());
}

#[test]
fn stats_use_nearest_rank_percentiles() {
    let s = Stats::of((1..=100).map(f64::from).chain([f64::NAN]));
    assert_eq!(
        (s.count, s.min, s.p05, s.p50, s.p95, s.max),
        (100, 1.0, 5.0, 50.0, 95.0, 100.0)
    );
    assert!((s.mean - 50.5).abs() < 1e-12);
    assert_eq!(Stats::of([]).count, 0);
}
