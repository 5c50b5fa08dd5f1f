//! Diagnostics for issue 3: per-level Newton effort and Jacobian singular values.
use std::time::Instant;

use lowthrust_ground::solver::shooting::{newton, ShootingProblem, TransferShooting};
use lowthrust_ground::solver::{transfer_guesses, SolveOptions};
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn main() {
    if std::env::var_os("GUESS").is_some() {
        return guess();
    }
    if std::env::var_os("HOMO").is_some() {
        return homo();
    }
    if std::env::var_os("ERR").is_some() {
        return err();
    }
    if std::env::var_os("VALLEY").is_some() {
        return valley();
    }
    if std::env::var_os("FULL").is_some() {
        return full();
    }
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let opts = SolveOptions::default();
    let index: u64 = std::env::var("IDX").ok().and_then(|s| s.parse().ok()).unwrap_or(0);
    let kind = ScenarioKind::TransferCircular;
    let scenario = kind.draw(7, index);
    println!(
        "a0 {:.4} af {:.4} N {} nu0 {:.3}",
        scenario.initial.shape.a, scenario.target.a, scenario.steps, scenario.initial.nu
    );
    let p = TransferShooting {
        scenario: &scenario,
        spacecraft: sc,
    };
    let g = transfer_guesses(&scenario);
    let t = Instant::now();
    let _ = p.residual(1.0, &g[0], &opts.tolerances);
    println!("one sens residual {:?}", t.elapsed());
    let t = Instant::now();
    let _ = p.residual_only(1.0, &g[0], &opts.tolerances);
    println!("one plain residual {:?}", t.elapsed());
    let mut z = None;
    for z0 in &g {
        let o = newton(&p, 1.0, z0, &opts.tolerances, &opts.start_newton).unwrap();
        if o.converged {
            z = Some(o.z);
            break;
        }
    }
    let mut z = z.unwrap();
    let mut eps = 1.0f64;
    let mut ratio = 0.5;
    while eps > 5e-5 {
        let next = eps * ratio;
        let t = Instant::now();
        let o = newton(&p, next, &z, &opts.tolerances, &opts.newton).unwrap();
        let (f, j) = p.residual(next, &o.z, &opts.tolerances).unwrap();
        let sv = j.svd(false, false).singular_values;
        let mut s: Vec<f64> = sv.iter().copied().collect();
        s.sort_by(|a, b| b.total_cmp(a));
        println!(
            "eps {next:.3e} conv {} it {} res {:.2e} {:?} sv {:?} z {:?}",
            o.converged,
            o.iterations,
            f.amax(),
            t.elapsed(),
            s.iter().map(|x| format!("{x:.1e}")).collect::<Vec<_>>(),
            o.z.as_slice().iter().map(|x| format!("{x:.5}")).collect::<Vec<_>>()
        );
        if o.converged {
            z = o.z;
            eps = next;
            ratio = 0.5;
        } else {
            ratio = ratio.sqrt();
            if ratio > 0.98 {
                break;
            }
        }
    }
}

fn full() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let mut opts = SolveOptions::default();
    if let Some(w) = std::env::var("START_WORK").ok().and_then(|s| s.parse().ok()) {
        opts.max_start_work = w;
    }
    if let Some(w) = std::env::var("START_IT").ok().and_then(|s| s.parse().ok()) {
        opts.start_newton.max_iterations = w;
    }
    let kind = match std::env::var("KIND").as_deref() {
        Ok("hard") => ScenarioKind::TransferHard,
        Ok("rv") => ScenarioKind::RendezvousCircular,
        _ => ScenarioKind::TransferCircular,
    };
    let n: u64 = std::env::var("N").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
    let i0: u64 = std::env::var("IDX").ok().and_then(|s| s.parse().ok()).unwrap_or(0);
    for index in i0..i0 + n {
        let scenario = kind.draw(7, index);
        let w0 = lowthrust_ground::solver::pontryagin::work_done();
        let r = lowthrust_ground::solver::solve_scenario(kind, 7, index, &scenario, &sc, &opts);
        print!(
            "work {:.2}M ",
            (lowthrust_ground::solver::pontryagin::work_done() - w0) as f64 * 1e-6
        );
        println!("case {index}: a0 {:.3} af {:.3} e0 {:.3} ef {:.3} N {} conv {} eps {:.2e} res {:.1e} m {:.6} arcs {} optima {} {:.2}s {:?}",
            scenario.initial.shape.a, scenario.target.a, scenario.initial.shape.e, scenario.target.e, scenario.steps,
            r.converged, r.final_eps, r.residual, r.final_mass, r.thrust_arcs, r.distinct_energy_optima, r.seconds, r.failure);
    }
}

fn valley() {
    use lowthrust_ground::solver::pontryagin::{idx, switching_function, OptimalControlParams, StateCostate};
    use lowthrust_ground::solver::shooting::{initial_state_costate, TransferVector};
    use onboard::integrator::integrate;
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let opts = SolveOptions::default();
    let scenario = ScenarioKind::TransferCircular.draw(7, 0);
    let p = TransferShooting {
        scenario: &scenario,
        spacecraft: sc,
    };
    let eps = 1.205e-2;
    let z = TransferVector::from_column_slice(&[
        0.09473857790283569,
        0.6357726325769049,
        -0.7155108345922938,
        0.10393619036621489,
        0.06646030812892577,
        11.90867077813118,
    ]);
    let (f, j) = p.residual(eps, &z, &opts.tolerances).unwrap();
    println!("res {:.2e}", f.amax());
    let svd = j.clone_owned();
    let d = nalgebra::DMatrix::from_column_slice(6, 6, svd.as_slice()).svd(true, true);
    println!("sv {:?}", d.singular_values.as_slice());
    let vt = d.v_t.unwrap();
    let imin = (0..6)
        .min_by(|&a, &b| d.singular_values[a].total_cmp(&d.singular_values[b]))
        .unwrap();
    let v: Vec<f64> = (0..6).map(|k| vt[(imin, k)]).collect();
    println!("weak dir {:?}", v);
    let y0 = initial_state_costate(&scenario, &[z[0], z[1], z[2], z[3], z[4]]);
    let params = OptimalControlParams { spacecraft: sc, eps };
    let tof = scenario.time_of_flight();
    let mut y = y0;
    let mut t = 0.0;
    let mut line = String::new();
    for k in 1..=80 {
        let t1 = tof * k as f64 / 80.0;
        y = integrate(&StateCostate(params), t, &y, t1, &opts.tolerances).unwrap().0;
        t = t1;
        let rho = switching_function(&y, sc.exhaust_speed);
        line.push(if rho > eps {
            '#'
        } else if rho < -eps {
            '.'
        } else {
            '~'
        });
    }
    println!("throttle {line} m {}", y[idx::M]);
    for s in [-0.3, -0.1, -0.03, -0.01, 0.01, 0.03, 0.1, 0.3] {
        let zt = z + TransferVector::from_column_slice(&v) * s;
        let (ft, _) = p.residual(eps, &zt, &opts.tolerances).unwrap();
        println!("s {s}: |F| {:.3e}", ft.norm());
    }
}

fn err() {
    use lowthrust_ground::solver::shooting::{RendezvousShooting, RendezvousVector};
    use onboard::integrator::Tolerances;
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let opts = SolveOptions::default();
    let scenario = ScenarioKind::RendezvousCircular.draw(7, 1);
    let p = RendezvousShooting {
        scenario: &scenario,
        spacecraft: sc,
    };
    let z = RendezvousVector::from_column_slice(&[
        0.4427978829192794,
        0.35977347144433885,
        0.5617322796640071,
        0.9231269138449006,
        0.35548547542988956,
    ]);
    for eps in [
        1.22e-4,
        8.63e-5,
        6.1035e-5,
        6.1035e-5 * (1.0 + 1e-4),
        6.1035e-5 * (1.0 - 1e-4),
    ] {
        let r = p.residual(eps, &z, &opts.tolerances).map(|(f, _)| f.amax());
        let r2 = p.residual_only(eps, &z, &opts.tolerances).map(|f| f.amax());
        let big = Tolerances {
            max_steps: 1_000_000,
            ..opts.tolerances
        };
        let t = std::time::Instant::now();
        let r3 = p.residual(eps, &z, &big).map(|(f, _)| f.amax());
        println!(
            "eps {eps:e}: sens {r:?} plain {r2:?} big-budget {r3:?} {:?}",
            t.elapsed()
        );
    }
}

fn homo() {
    use lowthrust_ground::solver::shooting::NewtonSettings;
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let opts = SolveOptions::default();
    let index: u64 = std::env::var("IDX").ok().and_then(|s| s.parse().ok()).unwrap_or(0);
    let scenario = ScenarioKind::TransferCircular.draw(7, index);
    let p = TransferShooting {
        scenario: &scenario,
        spacecraft: sc,
    };
    let tol = opts.tolerances;
    let mut z = None;
    for z0 in transfer_guesses(&scenario) {
        let o = newton(&p, 1.0, &z0, &tol, &opts.start_newton).unwrap();
        if o.converged {
            z = Some(o.z);
            break;
        }
    }
    let mut z = z.unwrap();
    let settings = NewtonSettings {
        max_iterations: 15,
        tolerance: 1e-8,
    };
    let mut eps = 1.0f64;
    let mut ratio = 0.5f64;
    let t0 = Instant::now();
    while eps > 6.1e-5 {
        let next = (eps * ratio).max(6.103515625e-5);
        let (_, j) = p.residual(eps, &z, &tol).unwrap();
        let h = eps * 1e-4;
        let df =
            (p.residual_only(eps + h, &z, &tol).unwrap() - p.residual_only(eps - h, &z, &tol).unwrap()) / (2.0 * h);
        let tangent = j.lu().solve(&(-df)).unwrap_or_default();
        let pred = z + tangent * (next - eps);
        let o = newton(&p, next, &pred, &tol, &settings);
        let d = nalgebra::DMatrix::from_column_slice(6, 6, j.as_slice()).svd(false, false);
        let mut sv: Vec<f64> = d.singular_values.iter().copied().collect();
        sv.sort_by(|a, b| b.total_cmp(a));
        match o {
            Ok(o) => {
                println!(
                    "{:.1}s eps {next:.3e} conv {} it {} res {:.1e} sv {:.1e}..{:.1e} dnu {:.4} z {:?}",
                    t0.elapsed().as_secs_f64(),
                    o.converged,
                    o.iterations,
                    o.residual,
                    sv[0],
                    sv[5],
                    tangent[5] * (next - eps),
                    o.z.as_slice().iter().map(|x| format!("{x:.6}")).collect::<Vec<_>>()
                );
                if o.converged {
                    z = o.z;
                    eps = next;
                    ratio = (ratio * ratio).max(0.5);
                } else {
                    ratio = ratio.sqrt();
                }
            }
            Err(e) => {
                println!("eps {next:.3e} err {e:?}");
                ratio = ratio.sqrt();
            }
        }
        if ratio > 0.999 {
            break;
        }
    }
}

fn guess() {
    use lowthrust_ground::solver::pontryagin::work_done;
    use lowthrust_ground::solver::shooting::NewtonSettings;
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let opts = SolveOptions::default();
    let kind = match std::env::var("KIND").as_deref() {
        Ok("hard") => ScenarioKind::TransferHard,
        _ => ScenarioKind::TransferCircular,
    };
    let n: u64 = std::env::var("N").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
    let i0: u64 = std::env::var("IDX").ok().and_then(|s| s.parse().ok()).unwrap_or(0);
    let settings = NewtonSettings {
        max_iterations: 40,
        tolerance: 1e-8,
    };
    for index in i0..i0 + n {
        let scenario = kind.draw(7, index);
        let p = TransferShooting {
            scenario: &scenario,
            spacecraft: sc,
        };
        let mut line = String::new();
        for (k, z0) in transfer_guesses(&scenario).iter().enumerate() {
            let w = work_done();
            let o = newton(&p, 1.0, z0, &opts.tolerances, &settings);
            let w = (work_done() - w) / 1000;
            match o {
                Ok(o) if o.converged => line += &format!(" {k}:ok{}it/{w}k", o.iterations),
                _ => line += &format!(" {k}:-/{w}k"),
            }
        }
        println!("case {index}:{line}");
    }
}
