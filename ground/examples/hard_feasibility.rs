//! A crude feasibility indicator for transfer-hard draws (issue 3): the delta-v the engine can
//! give in the time of flight at full thrust, c ln(1 / (1 - T tf / c)), against a lower estimate
//! of the delta-v the transfer needs, max(|dE| / v_max, |dh| / r_max) with v_max the largest
//! speed and r_max the largest radius on either orbit. Not a proof (the transfer may go faster or
//! farther out than either orbit); the ratio ranks the draws.
//!
//! SEED=7 N=100 cargo run --release -p lowthrust-ground --example hard_feasibility
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;

fn main() {
    let sc = Spacecraft::MSR_ERO.canonical().unwrap();
    let get = |k: &str, d: u64| std::env::var(k).ok().and_then(|s| s.parse().ok()).unwrap_or(d);
    let (seed, n) = (get("SEED", 7), get("N", 100));
    println!("index,a0,e0,af,ef,tof,dv_available,dv_estimate,ratio");
    for index in 0..n {
        let s = ScenarioKind::TransferHard.draw(seed, index);
        let (o, t) = (s.initial.shape, s.target);
        let tof = s.time_of_flight();
        let burn = sc.thrust * tof / sc.exhaust_speed;
        let available = if burn < 1.0 {
            sc.exhaust_speed * (1.0 / (1.0 - burn)).ln()
        } else {
            f64::INFINITY
        };
        let energy = |a: f64| -0.5 / a;
        let h = |a: f64, e: f64| (a * (1.0 - e * e)).sqrt();
        let v_peri = |a: f64, e: f64| ((1.0 + e) / (a * (1.0 - e))).sqrt();
        let v_max = v_peri(o.a, o.e).max(v_peri(t.a, t.e));
        let r_max = (o.a * (1.0 + o.e)).max(t.a * (1.0 + t.e));
        let estimate = ((energy(t.a) - energy(o.a)).abs() / v_max).max((h(t.a, t.e) - h(o.a, o.e)).abs() / r_max);
        println!(
            "{index},{:.4},{:.4},{:.4},{:.4},{tof:.3},{available:.4},{estimate:.4},{:.3}",
            o.a,
            o.e,
            t.a,
            t.e,
            estimate / available
        );
    }
}
