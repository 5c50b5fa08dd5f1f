//! Issue 3 exploration: the structure-fixed (bang-bang) fuel-optimal transfer on transfer-circular
//! draws. For a range of shifts of the burn pattern (centre of the first burn), solves the pinned
//! structured problem, prints the transversality residual (the free problem's missing condition),
//! the final mass and the switching function on the coasts; then the free structured problem.
//!
//! IDX=0 SHIFTS=7 cargo run --release -p lowthrust-ground --example circ_bangbang
use std::time::Instant;

use lowthrust_ground::solver::bangbang::{BangBangTransfer, Hohmann, Structure};
use lowthrust_ground::solver::pontryagin::{idx, Regime};
use lowthrust_ground::solver::pontryagin::{propagate, ramp_fraction, OptimalControlParams};
use lowthrust_ground::solver::shooting::initial_state_costate;
use lowthrust_ground::solver::shooting::{homotopy_tangent, PinnedAnomalyTransfer, RendezvousVector};
use lowthrust_ground::solver::shooting::{newton, NewtonSettings, ShootingProblem, TransferShooting, TransferVector};
use lowthrust_ground::solver::SolveOptions;
use nalgebra::SVector;
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

std::thread_local! { static MAXF: f64 = std::env::var("MAXF").ok().and_then(|s| s.parse().ok()).unwrap_or(4.0); }

fn main() {
    if std::env::var_os("CHECK").is_some() {
        return check();
    }
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let opts = SolveOptions::default();
    let tol = opts.tolerances;
    let index: u64 = std::env::var("IDX").ok().and_then(|s| s.parse().ok()).unwrap_or(0);
    let shifts: usize = std::env::var("SHIFTS").ok().and_then(|s| s.parse().ok()).unwrap_or(7);
    let kind = ScenarioKind::TransferCircular;
    let scenario = kind.draw(7, index);
    let tof = scenario.time_of_flight();
    let h = Hohmann::of(&scenario, &sc);
    let (lo, hi) = h.centre_range(tof);
    println!(
        "case {index}: a0 {:.4} af {:.4} N {} tof {:.3} theta0 {:.3}; Hohmann m_f {:.7} burns {:.3} {:.3} half {:.3}; centre range {:.3}..{:.3}",
        scenario.initial.shape.a,
        scenario.target.a,
        scenario.steps,
        tof,
        scenario.initial.polar().theta,
        h.final_mass,
        h.burn[0],
        h.burn[1],
        h.half_period,
        lo,
        hi
    );
    let structure = Structure {
        first: Regime::Coast,
        switches: 4,
    };
    let settings = NewtonSettings {
        max_iterations: 30,
        tolerance: 1e-10,
    };
    let mut best: Option<(SVector<f64, 10>, f64)> = None;
    for s in 0..shifts {
        let centre = lo + (hi - lo) * (s as f64 + 0.5) / shifts as f64;
        let g = h.guess(&scenario, centre);
        let pinned = BangBangTransfer {
            scenario: &scenario,
            spacecraft: sc,
            structure,
            pin: Some(g[6]),
        };
        let t = Instant::now();
        let z0 = SVector::<f64, 10>::from_column_slice(&g);
        let (f0, _) = pinned.evaluate(&g, &tol, false).unwrap();
        let out = newton(&pinned, 0.0, &z0, &tol, &settings).unwrap();
        let free = BangBangTransfer { pin: None, ..pinned };
        let (ff, jac) = free.evaluate(out.z.as_slice(), &tol, true).unwrap();
        let flight = free.fly(out.z.as_slice(), &tol, false).unwrap();
        let m_f = flight.y_final[idx::M];
        let jm = nalgebra::DMatrix::from_fn(10, 10, |i, k| jac[i][k]);
        let mut sv: Vec<f64> = jm.svd(false, false).singular_values.iter().copied().collect();
        sv.sort_by(|a, b| b.total_cmp(a));
        println!(
            "centre {centre:.3}: guess |F| {:.2e} -> conv {} it {} res {:.1e} ({:.0} ms) m_f {m_f:.9} transv {:+.3e} z {:?} sv {:?}",
            f0.iter().fold(0.0f64, |a, b| a.max(b.abs())),
            out.converged,
            out.iterations,
            out.residual,
            t.elapsed().as_secs_f64() * 1e3,
            ff[4],
            out.z.iter().map(|x| format!("{x:.5}")).collect::<Vec<_>>(),
            sv.iter().map(|x| format!("{x:.1e}")).collect::<Vec<_>>()
        );
        if out.converged && best.as_ref().is_none_or(|(_, m)| m_f > *m) {
            best = Some((out.z, m_f));
        }
    }
    let Some((zb, _)) = best else { return };
    // rho along the best pinned solution.
    let free = BangBangTransfer {
        scenario: &scenario,
        spacecraft: sc,
        structure,
        pin: None,
    };
    rho_profile(&scenario, &sc, &zb, &tol);
    let t = Instant::now();
    let out = newton(&free, 0.0, &zb, &tol, &settings).unwrap();
    let flight = free.fly(out.z.as_slice(), &tol, false).unwrap();
    println!(
        "free structured: conv {} it {} res {:.1e} ({:.0} ms) m_f {:.9} z {:?}",
        out.converged,
        out.iterations,
        out.residual,
        t.elapsed().as_secs_f64() * 1e3,
        flight.y_final[idx::M],
        out.z.iter().map(|x| format!("{x:.6}")).collect::<Vec<_>>()
    );
    // The SPEC's smoothed single shooting at the final eps, from the bang-bang costates.
    let zs = if out.converged { out.z } else { zb };
    let shoot = TransferShooting {
        scenario: &scenario,
        spacecraft: sc,
    };
    let mut z6 = TransferVector::from_column_slice(&zs.as_slice()[..6]);
    if std::env::var_os("DOWN").is_some() {
        return down(&scenario, &sc, &zs.as_slice()[..6], &tol);
    }
    if std::env::var_os("PINNED").is_some() {
        return pinned(&scenario, &sc, &zs.as_slice()[..6], &tol);
    }
    // Upward continuation in eps from the bang-bang end to the SPEC's final level 2^-14.
    let t = Instant::now();
    let mut eps = 2f64.powi(-27);
    let target = 2f64.powi(-14);
    let mut factor = MAXF.with(|m| *m);
    let mut newtons = 0;
    let mut ok = true;
    let o = newton(&shoot, eps, &z6, &tol, &opts.newton).unwrap();
    println!("eps {eps:.3e}: conv {} it {}", o.converged, o.iterations);
    z6 = o.z;
    while eps < target {
        let next = (eps * factor).min(target);
        let pred = match lowthrust_ground::solver::shooting::homotopy_tangent(&shoot, &z6, eps, &tol) {
            Ok(Some(tg)) if std::env::var_os("NOPRED").is_none() => z6 + tg * (next - eps),
            _ => z6,
        };
        let o = newton(&shoot, next, &pred, &tol, &opts.newton).unwrap();
        newtons += 1;
        let mf = lowthrust_ground::solver::pontryagin::propagate(
            &lowthrust_ground::solver::pontryagin::OptimalControlParams {
                spacecraft: sc,
                eps: next,
            },
            0.0,
            &lowthrust_ground::solver::shooting::initial_state_costate(
                &scenario,
                &[o.z[0], o.z[1], o.z[2], o.z[3], o.z[4]],
            ),
            tof,
            &tol,
        )
        .map_or(f64::NAN, |y| y[idx::M]);
        let ramp = lowthrust_ground::solver::pontryagin::ramp_fraction(
            &lowthrust_ground::solver::pontryagin::OptimalControlParams {
                spacecraft: sc,
                eps: next,
            },
            &lowthrust_ground::solver::shooting::initial_state_costate(
                &scenario,
                &[o.z[0], o.z[1], o.z[2], o.z[3], o.z[4]],
            ),
            tof,
            &tol,
        )
        .unwrap_or(f64::NAN);
        println!(
            "  eps {next:.4e}: conv {} it {} res {:.1e} m_f {mf:.9} ramp {ramp:.3} |dz| {:.1e} z {:?}",
            o.converged,
            o.iterations,
            o.residual,
            (o.z - z6).amax(),
            o.z.iter().map(|x| format!("{x:.6}")).collect::<Vec<_>>()
        );
        if o.converged {
            eps = next;
            z6 = o.z;
            factor = (factor * 2.0).min(MAXF.with(|m| *m));
        } else {
            factor = factor.sqrt();
            if factor < 1.002 {
                ok = false;
                break;
            }
        }
    }
    let (f, jac) = shoot.residual(eps, &z6, &tol).unwrap();
    let mut sv: Vec<f64> = jac.svd(false, false).singular_values.iter().copied().collect();
    sv.sort_by(|a, b| b.total_cmp(a));
    let m = lowthrust_ground::solver::pontryagin::propagate(
        &lowthrust_ground::solver::pontryagin::OptimalControlParams { spacecraft: sc, eps },
        0.0,
        &lowthrust_ground::solver::shooting::initial_state_costate(&scenario, &[z6[0], z6[1], z6[2], z6[3], z6[4]]),
        tof,
        &tol,
    )
    .unwrap()[idx::M];
    println!(
        "upward: ok {ok} eps {eps:.3e} res {:.1e} newtons {newtons} ({:.0} ms) m_f {m:.9} z {:?} sv {:?}",
        f.amax(),
        t.elapsed().as_secs_f64() * 1e3,
        z6.iter().map(|x| format!("{x:.6}")).collect::<Vec<_>>(),
        sv.iter().map(|x| format!("{x:.1e}")).collect::<Vec<_>>()
    );
}

fn rho_profile(
    scenario: &shared::scenario::Scenario,
    sc: &shared::spacecraft::CanonicalSpacecraft,
    z: &SVector<f64, 10>,
    tol: &onboard::integrator::Tolerances,
) {
    use lowthrust_ground::solver::pontryagin::switching_function;
    let free = BangBangTransfer {
        scenario,
        spacecraft: *sc,
        structure: Structure {
            first: Regime::Coast,
            switches: 4,
        },
        pin: None,
    };
    let tof = scenario.time_of_flight();
    let n = 40;
    let mut line = String::new();
    for k in 0..=n {
        let t = tof * k as f64 / n as f64;
        let y = free.state_at(z.as_slice(), t, tol).unwrap();
        let rho = switching_function(&y, sc.exhaust_speed);
        line.push_str(&format!("{t:.2}:{rho:+.1e} "));
    }
    println!("rho(t): {line}");
}

/// Upward continuation in eps at the pinned nu_f, then a secant search on nu_f for the
/// transversality condition at the final eps.
fn pinned(
    scenario: &shared::scenario::Scenario,
    sc: &shared::spacecraft::CanonicalSpacecraft,
    z6: &[f64],
    tol: &onboard::integrator::Tolerances,
) {
    let opts = SolveOptions::default();
    let tof = scenario.time_of_flight();
    let t = Instant::now();
    let mut nu = z6[5];
    let mut z = RendezvousVector::from_column_slice(&z6[..5]);
    let problem = |nu: f64| PinnedAnomalyTransfer {
        scenario,
        spacecraft: *sc,
        nu_f: nu,
    };
    let maxf: f64 = std::env::var("MAXF").ok().and_then(|s| s.parse().ok()).unwrap_or(4.0);
    let mut eps = 2f64.powi(-27);
    let target = 2f64.powi(-14);
    let o = newton(&problem(nu), eps, &z, tol, &opts.newton).unwrap();
    println!(
        "pinned eps {eps:.3e}: conv {} it {} res {:.1e}",
        o.converged, o.iterations, o.residual
    );
    z = o.z;
    let mut factor = maxf;
    let mut solves = 0;
    while eps < target {
        let next = (eps * factor).min(target);
        let p = problem(nu);
        let pred = match homotopy_tangent(&p, &z, eps, tol) {
            Ok(Some(tg)) => z + tg * (next - eps),
            _ => z,
        };
        let o = newton(&p, next, &pred, tol, &opts.newton).unwrap();
        solves += 1;
        let params = OptimalControlParams {
            spacecraft: *sc,
            eps: next,
        };
        let y0 = initial_state_costate(scenario, &[o.z[0], o.z[1], o.z[2], o.z[3], o.z[4]]);
        let mf = propagate(&params, 0.0, &y0, tof, tol).map_or(f64::NAN, |y| y[idx::M]);
        let ramp = ramp_fraction(&params, &y0, tof, tol).unwrap_or(f64::NAN);
        let f5 = p.free_residual(next, &o.z, tol).map_or(f64::NAN, |f| f[4]);
        println!(
            "  eps {next:.4e}: conv {} it {} res {:.1e} m_f {mf:.9} ramp {ramp:.3} transv {f5:+.2e} |dz| {:.1e}",
            o.converged,
            o.iterations,
            o.residual,
            (o.z - z).amax()
        );
        if o.converged {
            if std::env::var_os("PRINTZ").is_some() {
                println!(
                    "Z={},{}",
                    o.z.iter().map(|x| format!("{x:.17e}")).collect::<Vec<_>>().join(","),
                    nu
                );
            }
            eps = next;
            z = o.z;
            factor = (factor * 2.0).min(maxf);
        } else {
            factor = factor.sqrt();
            if factor < 1.002 {
                println!("pinned continuation failed");
                return;
            }
        }
    }
    println!(
        "pinned continuation: {solves} solves, {:.0} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
    // Secant on nu_f for the transversality residual.
    let f5 = |nu: f64, z: &RendezvousVector| -> Option<(f64, RendezvousVector)> {
        let p = problem(nu);
        let o = newton(
            &p,
            eps,
            z,
            tol,
            &NewtonSettings {
                max_iterations: 10,
                tolerance: 1e-10,
            },
        )
        .ok()?;
        if !o.converged {
            println!(
                "    inner at nu {nu:.6} not converged: res {:.1e} it {}",
                o.residual, o.iterations
            );
            return None;
        }
        Some((p.free_residual(eps, &o.z, tol).ok()?[4], o.z))
    };
    let (mut f_a, mut z_a) = f5(nu, &z).unwrap();
    let mut nu_a = nu;
    let mut nu_b = nu + 1e-3;
    let (mut f_b, mut z_b) = f5(nu_b, &z_a).unwrap();
    println!("  nu {nu_a:.8} F5 {f_a:+.3e}; nu {nu_b:.8} F5 {f_b:+.3e}");
    for _ in 0..30 {
        if f_b.abs() < 1e-10 {
            break;
        }
        let slope = (f_b - f_a) / (nu_b - nu_a);
        let step = (-f_b / slope).clamp(-0.3, 0.3);
        let nu_c = nu_b + step;
        let Some((f_c, z_c)) = f5(nu_c, &z_b) else { break };
        println!("  nu {nu_c:.8} F5 {f_c:+.3e}");
        (nu_a, f_a, z_a) = (nu_b, f_b, z_b);
        (nu_b, f_b, z_b) = (nu_c, f_c, z_c);
    }
    let _ = z_a;
    nu = nu_b;
    let full = TransferVector::from_column_slice(&[z_b[0], z_b[1], z_b[2], z_b[3], z_b[4], nu]);
    let shoot = TransferShooting {
        scenario,
        spacecraft: *sc,
    };
    let f = shoot.residual_only(eps, &full, tol).unwrap();
    let params = OptimalControlParams { spacecraft: *sc, eps };
    let y0 = initial_state_costate(scenario, &[z_b[0], z_b[1], z_b[2], z_b[3], z_b[4]]);
    let mf = propagate(&params, 0.0, &y0, tof, tol).unwrap()[idx::M];
    println!(
        "final: eps {eps:.4e} |F| {:.1e} F {:?} m_f {mf:.9} nu_f {nu:.6} total {:.0} ms",
        f.amax(),
        f.iter().map(|x| format!("{x:.1e}")).collect::<Vec<_>>(),
        t.elapsed().as_secs_f64() * 1e3
    );
}

/// CHECK=1: propagate the costates z (env Z, comma separated 6 values) at EPS and print the
/// residual, mass and the throttle profile.
pub fn check() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let tol = SolveOptions::default().tolerances;
    let index: u64 = std::env::var("IDX").ok().and_then(|s| s.parse().ok()).unwrap_or(0);
    let scenario = ScenarioKind::TransferCircular.draw(7, index);
    let z: Vec<f64> = std::env::var("Z")
        .unwrap()
        .split(',')
        .map(|s| s.parse().unwrap())
        .collect();
    let eps: f64 = std::env::var("EPS").unwrap().parse().unwrap();
    let params = OptimalControlParams { spacecraft: sc, eps };
    let y0 = initial_state_costate(&scenario, &[z[0], z[1], z[2], z[3], z[4]]);
    let tof = scenario.time_of_flight();
    let shoot = TransferShooting {
        scenario: &scenario,
        spacecraft: sc,
    };
    let f = shoot
        .residual_only(eps, &TransferVector::from_column_slice(&z), &tol)
        .unwrap();
    println!("F {:?}", f.iter().map(|x| format!("{x:.2e}")).collect::<Vec<_>>());
    for _ in 0..3 {
        let mf = propagate(&params, 0.0, &y0, tof, &tol).unwrap()[idx::M];
        let p = PinnedAnomalyTransfer {
            scenario: &scenario,
            spacecraft: sc,
            nu_f: z[5],
        };
        let f5 = p
            .free_residual(eps, &RendezvousVector::from_column_slice(&z[..5]), &tol)
            .unwrap()[4];
        let ramp = ramp_fraction(&params, &y0, tof, &tol).unwrap();
        let w0 = lowthrust_ground::solver::pontryagin::work_done();
        let _ = propagate(&params, 0.0, &y0, tof, &tol).unwrap();
        let w1 = lowthrust_ground::solver::pontryagin::work_done();
        let _ = lowthrust_ground::solver::pontryagin::propagate_sensitivity(&params, &y0, tof, &tol).unwrap();
        let w2 = lowthrust_ground::solver::pontryagin::work_done();
        println!(
            "single propagate m_f {mf:.9} F5 {f5:.3e} ramp {ramp} steps plain {} sens {}",
            w1 - w0,
            (w2 - w1) / 6
        );
    }
    let n = 60;
    let mut y = y0;
    let mut t = 0.0;
    let mut line = String::new();
    for k in 1..=n {
        let t1 = tof * k as f64 / n as f64;
        y = propagate(&params, t, &y, t1, &tol).unwrap();
        t = t1;
        let rho = lowthrust_ground::solver::pontryagin::switching_function(&y, sc.exhaust_speed);
        line.push_str(&format!("{t:.2}:{rho:+.1e}/m{:.5} ", y[idx::M]));
    }
    println!("{line}");
    let h = Hohmann::of(&scenario, &sc);
    println!("Hohmann bound {:.7}", h.final_mass);
}

/// The SPEC's downward homotopy (eps = 1, 1/2, ..) with nu_f pinned at the bang-bang value.
fn down(
    scenario: &shared::scenario::Scenario,
    sc: &shared::spacecraft::CanonicalSpacecraft,
    z6: &[f64],
    tol: &onboard::integrator::Tolerances,
) {
    let opts = SolveOptions::default();
    let t = Instant::now();
    let nu = z6[5];
    let p = PinnedAnomalyTransfer {
        scenario,
        spacecraft: *sc,
        nu_f: nu,
    };
    let mut start = None;
    for (k, g) in lowthrust_ground::solver::transfer_guesses(scenario).iter().enumerate() {
        let z0 = RendezvousVector::from_column_slice(&g.as_slice()[..5]);
        let o = newton(&p, 1.0, &z0, tol, &opts.start_newton).unwrap_or(
            lowthrust_ground::solver::shooting::NewtonOutcome {
                z: z0,
                residual: f64::INFINITY,
                iterations: 0,
                converged: false,
            },
        );
        if o.converged {
            println!(
                "energy start from guess {k} ({} it), {:.0} ms",
                o.iterations,
                t.elapsed().as_secs_f64() * 1e3
            );
            start = Some(o.z);
            break;
        }
    }
    let Some(z) = start else {
        println!("no energy start");
        return;
    };
    let levels = lowthrust_ground::solver::shooting::homotopy(&p, &z, tol, &opts.newton, 1e-4, 200).unwrap();
    for l in &levels {
        let params = OptimalControlParams {
            spacecraft: *sc,
            eps: l.eps,
        };
        let y0 = initial_state_costate(
            scenario,
            &[
                l.outcome.z[0],
                l.outcome.z[1],
                l.outcome.z[2],
                l.outcome.z[3],
                l.outcome.z[4],
            ],
        );
        let tof = scenario.time_of_flight();
        let mf = propagate(&params, 0.0, &y0, tof, tol).map_or(f64::NAN, |y| y[idx::M]);
        let ramp = ramp_fraction(&params, &y0, tof, tol).unwrap_or(f64::NAN);
        let f5 = p.free_residual(l.eps, &l.outcome.z, tol).map_or(f64::NAN, |f| f[4]);
        println!(
            "  eps {:.4e}: conv {} it {} res {:.1e} m_f {mf:.9} ramp {ramp:.3} transv {f5:+.2e}",
            l.eps, l.outcome.converged, l.outcome.iterations, l.outcome.residual
        );
    }
    println!(
        "down: {:.0} ms, work {}",
        t.elapsed().as_secs_f64() * 1e3,
        lowthrust_ground::solver::pontryagin::work_done()
    );
    let l = levels.iter().rev().find(|l| l.outcome.converged).unwrap();
    let t2 = Instant::now();
    for _ in 0..20 {
        let _ = p.residual_only(l.eps, &l.outcome.z, tol);
    }
    let plain = t2.elapsed().as_secs_f64() * 1e3 / 20.0;
    let t2 = Instant::now();
    let w0 = lowthrust_ground::solver::pontryagin::work_done();
    for _ in 0..20 {
        let _ = lowthrust_ground::solver::shooting::ShootingProblem::residual(&p, l.eps, &l.outcome.z, tol);
    }
    let w1 = lowthrust_ground::solver::pontryagin::work_done();
    println!(
        "at eps {:.3e}: plain {plain:.2} ms, sens {:.2} ms ({} steps)",
        l.eps,
        t2.elapsed().as_secs_f64() * 1e3 / 20.0,
        (w1 - w0) / 20 / 6
    );
}
