//! The main job (`ground run`): a small transfer dataset by the indirect method, pretraining,
//! RL from the pretrained model, Monte Carlo evaluation, and a Markdown report that links every
//! figure, all in one run folder. Each stage resumes from what an interrupted run left.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::config::ExperimentConfig;
use crate::env::batch::OutcomeSummary;
use crate::eval::{accuracy_line, gap_line, monte_carlo, MonteCarloReport};
use crate::experiment::{pretrain, train, ExperimentError, PhaseSummary, Start};
use crate::generate::{dataset_path, generate, read_dataset, Manifest, Shard, Summary};
use crate::io::atomic_write;
use crate::plot::plot_trajectories;
use crate::solver::SolveOptions;

/// What the main job produced.
#[derive(Debug, Clone)]
pub struct MainJob {
    pub report: PathBuf,
    pub dataset: Summary,
    pub pretrain: PhaseSummary,
    pub train: PhaseSummary,
    pub monte_carlo: MonteCarloReport,
    /// Wall time of each stage, s: generate, pretrain, train, evaluate.
    pub stage_seconds: [f64; 4],
}

/// Runs every stage into `run` and writes `run/report.md`.
pub fn run_main_job(config: &ExperimentConfig, run: &Path) -> Result<MainJob, ExperimentError> {
    let mut config = config.clone();
    let mut stage_seconds = [0.0; 4];

    // 1. Fuel-optimal demonstrations (resumable: finished records are skipped).
    let t = Instant::now();
    println!(
        "[1/4] solving {} {} trajectories (indirect method)",
        config.generate.count,
        config.scenario.name()
    );
    let dataset_dir = run.join("dataset");
    let spacecraft = config
        .env
        .spacecraft
        .canonical()
        .map_err(|e| ExperimentError::Mismatch(format!("spacecraft: {e:?}")))?;
    let manifest = Manifest {
        scenario: config.scenario,
        seed: config.generate.seed,
        count: config.generate.count,
    };
    let options = SolveOptions {
        final_eps: config.generate.final_eps,
        ..SolveOptions::default()
    };
    let dataset = generate(manifest, Shard::WHOLE, &dataset_dir, &spacecraft, &options, true)
        .map_err(|e| ExperimentError::Dataset(e.to_string()))?;
    // The figure is a convenience: a dataset that cannot be plotted is still a dataset.
    let _ = plot_dataset_sample(&dataset_dir, Shard::WHOLE);
    // Absolute, so the config's relative-path base cannot apply twice.
    config.pretrain.dataset = Some(std::path::absolute(&dataset_dir).unwrap_or(dataset_dir.clone()));
    stage_seconds[0] = t.elapsed().as_secs_f64();

    // 2. Pretraining on the demonstrations.
    let t = Instant::now();
    println!(
        "[2/4] pretraining: {} updates on the demonstration buffer",
        config.pretrain.updates
    );
    let pre = pretrain(&config, run, run)?;
    stage_seconds[1] = t.elapsed().as_secs_f64();

    // 3. RL from the pretrained model.
    let t = Instant::now();
    println!(
        "[3/4] training: {} environment steps from the pretrained model",
        config.train.env_steps
    );
    let rl = train(&config, run, Start::Pretrained)?;
    stage_seconds[2] = t.elapsed().as_secs_f64();

    // 4. Monte Carlo of the best model.
    let t = Instant::now();
    println!("[4/4] Monte Carlo: {} episodes", config.evaluate.episodes);
    let best = rl.folder.join("best.safetensors");
    let mc = monte_carlo(&config, &best, &run.join("mc"), None, None)?;
    stage_seconds[3] = t.elapsed().as_secs_f64();

    let report = run.join("report.md");
    let text = report_markdown(&config, run, &dataset, &pre, &rl, &mc, &stage_seconds);
    atomic_write(&report, text.as_bytes()).map_err(|e| ExperimentError::Io(report.clone(), e))?;
    Ok(MainJob {
        report,
        dataset,
        pretrain: pre,
        train: rl,
        monte_carlo: mc,
        stage_seconds,
    })
}

fn outcome_row(name: &str, o: &OutcomeSummary) -> String {
    format!(
        "| {name} | {:.4} ± {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {}/{} |\n",
        o.total_reward.mean,
        o.total_reward.std,
        o.final_mass.mean,
        o.terminal_position.p50,
        o.terminal_position.p95,
        o.terminal_velocity.p50,
        o.terminal_velocity.p95,
        o.completed,
        o.episodes
    )
}

fn phase_line(name: &str, p: &PhaseSummary) -> String {
    match &p.best {
        Some(b) => format!(
            "- **{name}**: {} updates, {} environment steps, {:.0} s. Best evaluation at {} updates / {} steps: reward {:.4} ± {:.4}, median terminal |dr| {:.4} AU, final mass {:.4}.\n",
            p.updates,
            p.env_steps,
            p.seconds,
            b.updates,
            b.env_steps,
            b.summary.total_reward.mean,
            b.summary.total_reward.std,
            b.summary.terminal_position.p50,
            b.summary.final_mass.mean
        ),
        None => format!("- **{name}**: {} updates, no evaluation yet.\n", p.updates),
    }
}

/// The run's report: what was done, the tables, and links to every figure drawn under `run`
/// (relative paths).
pub fn report_markdown(
    config: &ExperimentConfig,
    run: &Path,
    dataset: &Summary,
    pre: &PhaseSummary,
    rl: &PhaseSummary,
    mc: &MonteCarloReport,
    stage_seconds: &[f64; 4],
) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Main job report: {}\n", config.scenario.name());
    let _ = writeln!(
        s,
        "Stages: dataset {:.0} s, pretraining {:.0} s, training {:.0} s, Monte Carlo {:.0} s (total {:.1} min). The config is in [config.toml](config.toml).\n",
        stage_seconds[0],
        stage_seconds[1],
        stage_seconds[2],
        stage_seconds[3],
        stage_seconds.iter().sum::<f64>() / 60.0
    );
    let _ = writeln!(s, "## Fuel-optimal demonstrations\n");
    let masses = if dataset.converged > 0 {
        format!(
            "; final mass of the converged ones {:.4} (min {:.4}, max {:.4})",
            dataset.final_mass_mean, dataset.final_mass_min, dataset.final_mass_max
        )
    } else {
        String::new()
    };
    let _ = writeln!(
        s,
        "{} trajectories solved by the indirect method (seed {}), {} converged to eps < {:.0e} (rate {:.0}%); solve time mean {:.1} s, max {:.1} s{masses}. Trajectories whose homotopy stopped early are used at the eps they reached (`pretrain.records`).\n",
        dataset.records,
        dataset.seed,
        dataset.converged,
        config.generate.final_eps,
        100.0 * dataset.convergence_rate,
        dataset.seconds_mean,
        dataset.seconds_max,
    );
    let _ = writeln!(s, "![dataset trajectories](dataset/trajectories.svg)\n");
    let _ = writeln!(s, "Per-trajectory figures: [summary.csv](dataset/summary.csv).\n");
    let _ = writeln!(s, "## Learning\n");
    s.push_str(&phase_line("Pretraining", pre));
    s.push_str(&phase_line("RL from the pretrained model", rl));
    let _ = writeln!(
        s,
        "\n{} trajectory records gave {} demonstration tuples (SPEC section 7); they stay in the RL buffer.\n",
        pre.demonstration_records, pre.demonstration_tuples
    );
    for (folder, title) in [("pretrain", "Pretraining"), ("train-pretrained", "RL")] {
        let _ = writeln!(
            s,
            "**{title}**: [evaluations]({folder}/eval.csv), [losses]({folder}/updates.csv)\n"
        );
        for (file, alt) in [
            ("eval-reward.svg", "evaluation reward"),
            ("eval-residuals.svg", "terminal residuals"),
            ("critic-loss.svg", "critic loss"),
            ("actor-loss.svg", "actor loss"),
            ("temperature.svg", "temperature and entropy"),
        ] {
            let _ = writeln!(s, "![{title} {alt}]({folder}/{file})");
        }
        s.push('\n');
    }
    let _ = writeln!(s, "## Monte Carlo ({} episodes, seed {})\n", mc.episodes, mc.seed);
    let _ = writeln!(
        s,
        "| policy | episode reward | final mass | dr p50 (AU) | dr p95 (AU) | dv p50 | dv p95 | completed |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|");
    s.push_str(&outcome_row("learned (deterministic)", &mc.policy));
    s.push_str(&outcome_row("zero thrust", &mc.zero_thrust));
    s.push_str(&outcome_row("uniform random", &mc.random));
    let _ = writeln!(s, "\n{}\n", accuracy_line(mc));
    if let Some(gap) = gap_line(mc) {
        let _ = writeln!(s, "{gap} ([table](mc/optimality-gap.csv))\n");
    }
    let _ = writeln!(s, "![Monte Carlo histograms](mc/histograms.svg)\n");
    let _ = writeln!(s, "![trajectories flown by the policy](mc/trajectories.svg)\n");
    let _ = writeln!(
        s,
        "Per-episode figures: [mc.csv](mc/mc.csv); summary: [summary.json](mc/summary.json).\n"
    );
    note_missing_figures(&s, run)
}

/// Replaces the image lines of `report` whose figure is absent under `run` (too few points to
/// draw) by a note, so every link of the report resolves.
fn note_missing_figures(report: &str, run: &Path) -> String {
    report
        .lines()
        .map(|line| match (line.strip_prefix("!["), line.rfind("](")) {
            (Some(_), Some(i)) if line.ends_with(')') && !run.join(&line[i + 2..line.len() - 1]).exists() => {
                format!("({} was not drawn: too few points)", &line[i + 2..line.len() - 1])
            }
            _ => line.to_string(),
        })
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}

/// Plots the first four solved trajectories of a dataset folder (thesis Fig. 4.4/4.5) into
/// `trajectories.svg` there; returns how many were drawn.
pub fn plot_dataset_sample(out: &Path, shard: Shard) -> Result<usize, Box<dyn std::error::Error>> {
    let file = read_dataset(&dataset_path(out, shard))?;
    let shown: Vec<_> = file
        .records
        .iter()
        .filter(|r| !r.ephemeris.is_empty())
        .take(4)
        .collect();
    if !shown.is_empty() {
        plot_trajectories(&shown, &out.join("trajectories.svg"))?;
    }
    Ok(shown.len())
}

/// Relative links of a Markdown report whose target file does not exist (for the tests).
pub fn broken_links(report: &Path) -> Vec<String> {
    let Ok(text) = std::fs::read_to_string(report) else {
        return vec![report.display().to_string()];
    };
    let base = report.parent().unwrap_or(Path::new("."));
    let mut broken = Vec::new();
    let mut rest = text.as_str();
    while let Some(i) = rest.find("](") {
        rest = &rest[i + 2..];
        let Some(end) = rest.find(')') else { break };
        let link = &rest[..end];
        if !link.contains("://") && !base.join(link).exists() {
            broken.push(link.to_string());
        }
        rest = &rest[end..];
    }
    broken
}
