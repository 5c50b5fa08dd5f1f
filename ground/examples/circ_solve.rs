//! Runs the near-circular transfer solver (solver::circular) on transfer-circular draws and prints
//! the outcome, the path taken, the effort and the final mass against the Hohmann bound.
//!
//! SEED=7 IDX=0 N=20 cargo run --release -p lowthrust-ground --example circ_solve
//! (CASES=37,59 for a list of indices)
use std::time::Instant;

use lowthrust_ground::solver::bangbang::Hohmann;
use lowthrust_ground::solver::pontryagin::{propagate, work_done, OptimalControlParams};
use lowthrust_ground::solver::shooting::initial_state_costate;
use lowthrust_ground::solver::{circular, SolveOptions};
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn main() {
    if let Ok(list) = std::env::var("LIST") {
        for i in list.split(',') {
            let sc = ScenarioKind::TransferCircular.draw(7, i.parse().unwrap());
            println!(
                "{i}: a0 {:.4} af {:.4} da {:+.4}",
                sc.initial.shape.a,
                sc.target.a,
                sc.target.a - sc.initial.shape.a
            );
        }
        return;
    }
    if std::env::var_os("TIMING").is_some() {
        return timing();
    }
    if std::env::var_os("DIAG").is_some() {
        return diag();
    }
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let mut opts = SolveOptions::default();
    if let Some(k) = std::env::var("WORK_SCALE").ok().and_then(|s| s.parse::<u64>().ok()) {
        opts.max_homotopy_work *= k;
        opts.max_start_work *= k;
        opts.max_homotopy_solves *= k as u32;
    }
    if let Some(r) = std::env::var("RTOL").ok().and_then(|s| s.parse::<f64>().ok()) {
        opts.tolerances.relative = r;
        opts.tolerances.absolute = 0.1 * r;
    }
    let get = |k: &str, d: u64| std::env::var(k).ok().and_then(|s| s.parse().ok()).unwrap_or(d);
    let (seed, i0, n) = (get("SEED", 7), get("IDX", 0), get("N", 10));
    // CASES=37,59,..: those indices instead of IDX..IDX+N.
    let indices: Vec<u64> = std::env::var("CASES").map_or_else(
        |_| (i0..i0 + n).collect(),
        |list| list.split(',').filter_map(|i| i.trim().parse().ok()).collect(),
    );
    let n = indices.len() as u64;
    let (mut ok, mut total) = (0, 0.0);
    for index in indices {
        let scenario = ScenarioKind::TransferCircular.draw(seed, index);
        let t = Instant::now();
        let w = work_done();
        let r = circular::solve(&scenario, &sc, &opts);
        let secs = t.elapsed().as_secs_f64();
        total += secs;
        let work = (work_done() - w) as f64 * 1e-6;
        let bound = Hohmann::of(&scenario, &sc).final_mass;
        match r {
            Ok(s) => {
                let m = s.final_mass;
                if s.residual < 1e-8 {
                    ok += 1;
                }
                println!(
                    "case {index}: a0 {:.3} af {:.3} ok res {:.1e} eps {:.2e} {} switches {:?} m_f {m:.9} bound {bound:.9} ({:+.1e}) {secs:.3}s work {work:.2}M",
                    scenario.initial.shape.a,
                    scenario.target.a,
                    s.residual,
                    s.eps,
                    if s.initial_coast { "C" } else { "B" },
                    s.switches.iter().map(|t| format!("{t:.3}")).collect::<Vec<_>>(),
                    m / bound - 1.0
                );
            }
            Err(e) => println!(
                "case {index}: a0 {:.3} af {:.3} FAILED {e} {secs:.2}s work {work:.2}M",
                scenario.initial.shape.a, scenario.target.a
            ),
        }
    }
    println!("{ok}/{n} converged, {:.2} s per case", total / n as f64);
}

/// DIAG=1: follow the pinned problem down to EPS_A, then probe Newton towards EPS_B.
pub fn diag() {
    use lowthrust_ground::solver::shooting::{
        homotopy, newton, predict, PinnedAnomalyTransfer, RendezvousVector, ShootingProblem,
    };
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let opts = SolveOptions::default();
    let mut tol = opts.tolerances;
    if let Some(r) = std::env::var("RTOL").ok().and_then(|s| s.parse::<f64>().ok()) {
        tol.relative = r;
        tol.absolute = r * 0.1;
        tol.max_steps = 20000;
    }
    let get = |k: &str, d: u64| std::env::var(k).ok().and_then(|s| s.parse().ok()).unwrap_or(d);
    let scenario = ScenarioKind::TransferCircular.draw(get("SEED", 7), get("IDX", 6));
    let nu: f64 = std::env::var("NU").unwrap().parse().unwrap();
    let eps_a: f64 = std::env::var("EPS_A").unwrap().parse().unwrap();
    let eps_b: f64 = std::env::var("EPS_B").unwrap().parse().unwrap();
    let p = PinnedAnomalyTransfer {
        scenario: &scenario,
        spacecraft: sc,
        nu_f: nu,
    };
    let mut z0 = None;
    for g in lowthrust_ground::solver::transfer_guesses(&scenario) {
        let o = newton(
            &p,
            1.0,
            &RendezvousVector::from_column_slice(&g.as_slice()[..5]),
            &tol,
            &opts.start_newton,
        )
        .unwrap();
        if o.converged {
            z0 = Some(o.z);
            break;
        }
    }
    let levels = homotopy(&p, &z0.unwrap(), &tol, &opts.newton, eps_a * 1.01, 200).unwrap();
    let l = levels.last().unwrap();
    println!("reached eps {:.4e} conv {}", l.eps, l.outcome.converged);
    let (eps, z) = (l.eps, l.outcome.z);
    {
        use lowthrust_ground::solver::pontryagin::switching_function;
        let params = OptimalControlParams { spacecraft: sc, eps };
        let mut y = initial_state_costate(&scenario, &[z[0], z[1], z[2], z[3], z[4]]);
        let tof = scenario.time_of_flight();
        let n = 200;
        let mut t = 0.0;
        let mut line = String::new();
        for k in 1..=n {
            let t1 = tof * k as f64 / n as f64;
            y = propagate(&params, t, &y, t1, &tol).unwrap();
            t = t1;
            let rho = switching_function(&y, sc.exhaust_speed) / eps;
            if rho.abs() < 3.0 {
                line.push_str(&format!("{t:.2}:{rho:+.2} "));
            }
        }
        println!("rho/eps where |rho| < 3 eps: {line}");
    }
    let pred = predict(&p, &z, eps, eps_b, None, &tol);
    let o = newton(&p, eps_b, &pred, &tol, &opts.newton).unwrap();
    println!(
        "library newton: conv {} it {} res {:.1e} z0 {:.17e} pred0 {:.17e} eps {eps:.6e}",
        o.converged, o.iterations, o.residual, z[0], pred[0]
    );
    let mut x = pred;
    for it in 0..12 {
        let (f, j) = p.residual(eps_b, &x, &tol).unwrap();
        let svd = j.svd(true, true);
        let mut sv: Vec<f64> = svd.singular_values.iter().copied().collect();
        sv.sort_by(|a, b| b.total_cmp(a));
        let step = j.lu().solve(&(-f)).unwrap();
        let mut line = String::new();
        for a in [1.0, 0.5, 0.25, 0.125, 1e-2, 1e-3, 1e-4] {
            let ft = p
                .residual_only(eps_b, &(x + step * a), &tol)
                .map_or(f64::NAN, |f| f.norm());
            let lin = (f + j * step * a).norm();
            line.push_str(&format!(" a={a}:{ft:.2e}(lin {lin:.2e})"));
        }
        println!(
            "it {it}: |F| {:.2e} |step| {:.1e} sv {:?}\n   {line}",
            f.norm(),
            step.amax(),
            sv.iter().map(|s| format!("{s:.1e}")).collect::<Vec<_>>()
        );
        // Plain vs sensitivity residual at x.
        let fp = p.residual_only(eps_b, &x, &tol).unwrap();
        println!("   plain-sens |dF| {:.1e}", (fp - f).amax());
        // Finite-difference check of J along the step.
        let h = 1e-7 / step.amax().max(1e-300);
        let fd = (p.residual_only(eps_b, &(x + step * h), &tol).unwrap()
            - p.residual_only(eps_b, &(x - step * h), &tol).unwrap())
            / (2.0 * h);
        println!(
            "   J*step vs FD: {:.2e} rel",
            (fd - j * step).norm() / (j * step).norm()
        );
        if std::env::var_os("LOOKAHEAD").is_some() {
            let x1 = x + step;
            let (f1, j1) = p.residual(eps_b, &x1, &tol).unwrap();
            let s1 = j1.lu().solve(&(-f1)).unwrap();
            let f2n = p.residual_only(eps_b, &(x1 + s1), &tol).unwrap().norm();
            println!("   lookahead: |F(x+s)| {:.2e} -> |F(x+s+s1)| {f2n:.2e}", f1.norm());
            if f2n < f.norm() {
                x = x1 + s1;
                continue;
            }
        }
        let mut a = 1.0;
        let f2 = f.norm_squared();
        loop {
            let ft = p
                .residual_only(eps_b, &(x + step * a), &tol)
                .map_or(f64::INFINITY, |f| f.norm_squared());
            if ft < f2 || a < 1e-4 {
                break;
            }
            a *= 0.5;
        }
        x += step * a;
    }
}

/// TIMING=1: cost of the building blocks on one case.
pub fn timing() {
    use lowthrust_ground::solver::multiple::MultipleShootingTransfer;
    use lowthrust_ground::solver::shooting::ShootingProblem;
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let opts = SolveOptions::default();
    let tol = opts.tolerances;
    let scenario = ScenarioKind::TransferCircular.draw(7, 0);
    let lambda0 = [0.096120, 0.638573, -0.719115, 0.103375, 0.066940];
    let ms = MultipleShootingTransfer {
        scenario: &scenario,
        spacecraft: sc,
        nu_f: 11.809,
    };
    for eps in [1.0, 1e-2, 6.1e-5] {
        let x = ms.unknowns_from_costates(&lambda0, eps, &tol).unwrap();
        let n = 20;
        let (w0, t0) = (work_done(), Instant::now());
        for _ in 0..n {
            let _ = ms.residual_only(eps, &x, &tol);
        }
        let (w1, t1) = (work_done(), Instant::now());
        for _ in 0..n {
            let _ = ms.residual(eps, &x, &tol);
        }
        let (w2, t2) = (work_done(), Instant::now());
        let (_, j) = ms.residual(eps, &x, &tol).unwrap();
        let t3 = Instant::now();
        for _ in 0..n {
            let _ = nalgebra::DMatrix::from_column_slice(55, 55, j.as_slice()).svd(true, true);
        }
        let t4 = Instant::now();
        let params = OptimalControlParams { spacecraft: sc, eps };
        let y0 = initial_state_costate(&scenario, &lambda0);
        let t5 = Instant::now();
        for _ in 0..n {
            let _ = lowthrust_ground::solver::pontryagin::propagate_sensitivity(
                &params,
                &y0,
                scenario.time_of_flight(),
                &tol,
            );
        }
        let t6 = Instant::now();
        println!(
            "eps {eps:.1e}: MS plain {:.2} ms ({} steps), MS STM {:.2} ms ({} steps), SVD55 {:.2} ms, single sens {:.2} ms",
            (t1 - t0).as_secs_f64() * 1e3 / n as f64,
            (w1 - w0) / n,
            (t2 - t1).as_secs_f64() * 1e3 / n as f64,
            (w2 - w1) / n / 10,
            (t4 - t3).as_secs_f64() * 1e3 / n as f64,
            (t6 - t5).as_secs_f64() * 1e3 / n as f64,
        );
    }
}
