//! Issue 4 diagnostic: does the policy reproduce the demonstrated throttles on the demonstration
//! states themselves (a fit question, apart from where the policy flies)? Reads one round's
//! relabels (`RUN/dagger/relabels-R.ltrl`) and prints the policy's deterministic throttle on the
//! same states: per trajectory, grouped by the mean demonstrated throttle; per step, grouped by
//! the demonstrated throttle; and the policy's direction length on coasting steps (the decoder
//! fires any direction longer than 1e-6). Measured in session 10: coasting steps (u = 5e-4) are
//! flown at 2 % throttle (docs/notes/issue4-dagger.md).
//!
//! cargo run --release -p lowthrust-ground --example throttle_fit -- CONFIG CHECKPOINT RELABELS ROUND
use lowthrust_ground::config::ExperimentConfig;
use lowthrust_ground::dagger::load_relabels;
use lowthrust_ground::env::{Environment, TransferEnv};
use lowthrust_ground::eval::load_agent;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let config = ExperimentConfig::load(std::path::Path::new(&args[0])).unwrap();
    let agent = load_agent(&config, TransferEnv::OBS, std::path::Path::new(&args[1])).unwrap();
    let round: u64 = args[3].parse().unwrap();
    let relabels = load_relabels(std::path::Path::new(&args[2]), round, TransferEnv::OBS).unwrap();
    let buf = &relabels.tuples;
    let n = buf.len();
    let mut obs = Vec::with_capacity(n * TransferEnv::OBS);
    for i in 0..n {
        obs.extend_from_slice(buf.get(i).obs);
    }
    let flown = agent.act(&obs, n, true);
    // buckets by demonstrated trajectory mean throttle
    let edges = [0.0, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.4, 1.01];
    let mut sums = vec![(0usize, 0.0f64, 0.0f64, 0.0f64); edges.len() - 1];
    let mut start = 0;
    for i in 0..n {
        if buf.get(i).done || i + 1 == n {
            let range = start..=i;
            let len = (i + 1 - start) as f64;
            let demo: f64 = range
                .clone()
                .map(|j| f64::from(buf.get(j).action[0] + 1.0) / 2.0)
                .sum::<f64>()
                / len;
            let pol: f64 = range.clone().map(|j| f64::from(flown[3 * j] + 1.0) / 2.0).sum::<f64>() / len;
            let abs: f64 = range
                .map(|j| (f64::from(flown[3 * j] - buf.get(j).action[0]) / 2.0).abs())
                .sum::<f64>()
                / len;
            let b = edges.windows(2).position(|w| demo >= w[0] && demo < w[1]).unwrap();
            sums[b].0 += 1;
            sums[b].1 += demo;
            sums[b].2 += pol;
            sums[b].3 += abs;
            start = i + 1;
        }
    }
    println!("demo mean throttle bucket | trajectories | demo mean | policy mean on same states | mean |du|");
    for (b, s) in sums.iter().enumerate() {
        if s.0 > 0 {
            let c = s.0 as f64;
            println!(
                "{:.3}-{:.3} | {} | {:.4} | {:.4} | {:.4}",
                edges[b],
                edges[b + 1],
                s.0,
                s.1 / c,
                s.2 / c,
                s.3 / c
            );
        }
    }
    // Per step, by demonstrated throttle.
    let step_edges = [0.0, 0.002, 0.01, 0.05, 0.2, 0.5, 0.8, 0.95, 0.99, 1.01];
    let mut steps = vec![(0usize, 0.0f64, 0.0f64); step_edges.len() - 1];
    for i in 0..n {
        let d = f64::from(buf.get(i).action[0] + 1.0) / 2.0;
        let p = f64::from(flown[3 * i] + 1.0) / 2.0;
        let b = step_edges.windows(2).position(|w| d >= w[0] && d < w[1]).unwrap();
        steps[b].0 += 1;
        steps[b].1 += d;
        steps[b].2 += p;
    }
    // The policy's direction length on coasting demonstrations (the decoder normalises any
    // length above 1e-6; the cloning loss softens it by 1e-2 in quadrature).
    let mut norms: Vec<f64> = (0..n)
        .filter(|&i| buf.get(i).action[0] < -0.996)
        .map(|i| f64::from(flown[3 * i + 1]).hypot(f64::from(flown[3 * i + 2])))
        .collect();
    norms.sort_by(f64::total_cmp);
    if !norms.is_empty() {
        let q = |f: f64| norms[((norms.len() - 1) as f64 * f) as usize];
        println!(
            "coast steps {}: policy |(a1,a2)| p10 {:.4} p50 {:.4} p90 {:.4}",
            norms.len(),
            q(0.1),
            q(0.5),
            q(0.9)
        );
    }
    println!("demo step throttle bucket | steps | demo mean | policy mean");
    for (b, s) in steps.iter().enumerate() {
        if s.0 > 0 {
            let c = s.0 as f64;
            println!(
                "{:.3}-{:.3} | {} | {:.4} | {:.4}",
                step_edges[b],
                step_edges[b + 1],
                s.0,
                s.1 / c,
                s.2 / c
            );
        }
    }
}
