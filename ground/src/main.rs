//! `ground`: the ground-side command line.
//!
//! Today it has the main job's entry point, `ground run`, which flies a demonstration through
//! the onboard crate. The pipeline it will run (indirect data generation, SAC pretraining and
//! training, Monte Carlo evaluation, export, SIL) lands with issues 3 to 6.

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use firmware_sim::{fly_transfer, ProxyTracking};
use onboard::features::RewardWeights;
use onboard::integrator::Tolerances;
use shared::orbit::{OrbitElements, OrbitShape};
use shared::scenario::{ProblemKind, Scenario};
use shared::spacecraft::Spacecraft;
use shared::units::{canonical_to_days, STEP};

#[derive(Parser)]
#[command(name = "ground", version, about = "Low-thrust guidance: ground trainer and tools")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The main job. For now: a feedback-law orbit raise flown step by step through the
    /// onboard guidance step, feature encoding and propagator (the learning pipeline comes later).
    Run {
        /// Initial circular orbit radius, AU.
        #[arg(long, default_value_t = 1.0)]
        a0: f64,
        /// Target circular orbit radius, AU.
        #[arg(long, default_value_t = 1.52)]
        af: f64,
        /// Initial polar angle, degrees.
        #[arg(long, default_value_t = 0.0)]
        nu0_deg: f64,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Run { a0, af, nu0_deg } => match demo(a0, af, nu0_deg) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("error: {e}");
                ExitCode::FAILURE
            }
        },
    }
}

fn demo(a0: f64, af: f64, nu0_deg: f64) -> Result<(), Box<dyn std::error::Error>> {
    println!("NOTE: the learning pipeline (indirect data generation, SAC, Monte Carlo, export) is not built yet.");
    println!("      This run flies a hand-tuned feedback law (ProxyTracking) through the onboard crate instead:");
    println!("      features -> actor -> command -> 14-day propagation, exactly the flight code path.\n");
    let spacecraft = Spacecraft::MSR_ERO;
    let sc = spacecraft.canonical().map_err(|e| format!("spacecraft: {e}"))?;
    let initial = OrbitElements {
        shape: OrbitShape {
            a: a0,
            e: 0.0,
            omega: 0.0,
        },
        nu: nu0_deg.to_radians(),
    };
    let target = OrbitShape {
        a: af,
        e: 0.0,
        omega: 0.0,
    };
    initial.validate().map_err(|e| format!("initial orbit: {e}"))?;
    target.validate().map_err(|e| format!("target orbit: {e}"))?;
    let scenario = Scenario {
        problem: ProblemKind::Transfer,
        initial,
        target,
        target_nu0: 0.0,
        steps: Scenario::steps_for(&initial.shape, &target),
    };
    println!(
        "spacecraft: {} N, Isp {} s, {} kg (canonical T = {:.7}, c = {:.7})",
        spacecraft.max_thrust_n, spacecraft.isp_s, spacecraft.initial_mass_kg, sc.thrust, sc.exhaust_speed
    );
    println!(
        "transfer: circular {a0} AU -> circular {af} AU, {} steps of 14 days ({:.0} days)\n",
        scenario.steps,
        canonical_to_days(scenario.time_of_flight())
    );
    let actor = ProxyTracking { target_a: af };
    let flight = fly_transfer(
        &actor,
        &scenario,
        &sc,
        &Tolerances::default(),
        &RewardWeights::default(),
    )?;
    println!(
        "{:>4} {:>8} | {:>7} {:>7} {:>8} {:>8} {:>7} {:>7} | {:>5} {:>7} {:>7} | {:>9}",
        "step", "t_tg", "r", "theta", "v_r", "v_th", "m", "r_t", "u", "a_r", "a_th", "reward"
    );
    for s in &flight.steps {
        let f = &s.features;
        println!(
            "{:>4} {:>8.4} | {:>7.4} {:>7.2} {:>8.5} {:>8.5} {:>7.4} {:>7.4} | {:>5.2} {:>7.4} {:>7.4} | {:>9.5}",
            s.index,
            f[9],
            f[0],
            f[2].atan2(f[1]).to_degrees(),
            f[3],
            f[4],
            f[5],
            f[6],
            s.command.throttle,
            s.command.alpha_r,
            s.command.alpha_theta,
            s.reward
        );
    }
    let end = flight.final_state();
    let res = flight.final_residuals().ok_or("no steps flown")?;
    let a_end = end.cartesian().elements().map_or(f64::NAN, |el| el.shape.a);
    println!(
        "\nfinal: a = {a_end:.4} AU, mass {:.4} m0 ({:.0} kg propellant), |dr| = {:.4} AU, |dv| = {:.4} v*, total reward {:.4}",
        end.m,
        (1.0 - end.m) * spacecraft.initial_mass_kg,
        res.position,
        res.velocity,
        flight.total_reward()
    );
    println!("one step = {STEP:.8} t*");
    Ok(())
}
