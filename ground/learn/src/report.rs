//! The run's Markdown report (`RUN/report.md`): what was done, the tables, and links to every
//! figure drawn in the run folder.

use std::fmt::Write as _;
use std::path::Path;

use crate::config::ExperimentConfig;
use crate::dagger::DaggerSummary;
use crate::eval::{accuracy_line, eccentricity_line, gap_line, solved_line};
use crate::export::ExportReport;
use crate::model::ModelCard;
use crate::phase::PhaseSummary;
use crate::pipeline::MainJob;
use crate::sil::{missed_thrust_bands, SilReport};
use ground_core::env::batch::OutcomeSummary;

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
pub fn report_markdown(config: &ExperimentConfig, run: &Path, job: &MainJob) -> String {
    let (dataset, pre, rl, mc) = (&job.dataset, &job.pretrain, &job.train, &job.monte_carlo);
    let mut s = String::new();
    let _ = writeln!(s, "# Run report: {}\n", config.display_name());
    let stages: Vec<String> = job
        .stage_seconds
        .iter()
        .map(|(name, seconds)| format!("{name} {seconds:.0} s"))
        .collect();
    let _ = writeln!(
        s,
        "Stages (wall time of this invocation; a resumed stage counts its resumed part): {} (total {:.1} min). The config is in [config.toml](config.toml).\n",
        stages.join(", "),
        job.stage_seconds.iter().map(|(_, t)| t).sum::<f64>() / 60.0
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
    if let Some(c) = &job.crosscheck {
        let repaired: Vec<String> = c
            .repaired
            .iter()
            .map(|(index, before, after)| format!("#{index} {before:.4} → {after:.4}"))
            .collect();
        let cut: Vec<String> = c
            .cut
            .iter()
            .map(|(index, record, direct)| format!("#{index} {record:.4}, direct {direct:.4}"))
            .collect();
        let listed = |items: &[String]| {
            if items.is_empty() {
                String::new()
            } else {
                format!(" ({})", items.join(", "))
            }
        };
        let _ = writeln!(
            s,
            "Checked against the direct transcription started on its own: {} converged records, {} direct solutions reached the target, {} of them ended heavier than the record by more than 1e-3 of the initial mass (worse local optima); {} re-solved onto the better optimum{}, {} that no re-solve lifted cut from the demonstrations{}. [crosscheck.json](dataset/crosscheck.json)\n",
            c.checked,
            c.direct_reached,
            c.beaten,
            c.repaired.len(),
            listed(&repaired),
            c.cut.len(),
            listed(&cut),
        );
    }
    let _ = writeln!(s, "![dataset trajectories](dataset/trajectories.svg)\n");
    let _ = writeln!(s, "Per-trajectory figures: [summary.csv](dataset/summary.csv).\n");
    let _ = writeln!(s, "## Learning\n");
    s.push_str(&phase_line("Pretraining", pre));
    s.push_str(&phase_line("RL from the pretrained model", rl));
    let _ = writeln!(
        s,
        "\n{} trajectory records gave {} demonstration tuples (docs/spec.md section 7); they stay in the RL buffer.\n",
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
    if let Some(rounds) = &job.dagger {
        let _ = writeln!(s, "## Relabelling rounds\n");
        rounds_section(&mut s, rounds, "dagger");
    }
    for stage in &job.stages {
        let _ = writeln!(s, "## Stage {}\n", stage.name);
        let _ = writeln!(
            s,
            "Its config, the recipe's with the stage's changes: [config.toml](stages/{0}/config.toml); {1}.\n",
            stage.name,
            stage.lineage_line()
        );
        rounds_section(&mut s, &stage.rounds, &format!("stages/{}/dagger", stage.name));
    }
    if !job.finetune.is_empty() {
        let _ = writeln!(s, "## Fine-tuning through the dynamics\n");
    }
    for fine in &job.finetune {
        // Each phase's folder, relative to the report beside RUN/finetune.
        let folder = fine.folder.strip_prefix(run).unwrap_or(&fine.folder).display();
        let _ = writeln!(
            s,
            "{}. [Evaluations]({folder}/steps.csv)\n\n![fine-tuning]({folder}/steps.svg)\n![terminal residuals]({folder}/steps-residuals.svg)\n",
            fine.lineage_line()
        );
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
    for band in &mc.accuracy_by_eccentricity {
        let _ = writeln!(s, "- {}", eccentricity_line(band));
    }
    if let Some(line) = solved_line(mc) {
        let _ = writeln!(s, "\n{line}\n");
    }
    if let Some(gap) = gap_line(mc) {
        let _ = writeln!(s, "{gap} ([table](mc/optimality-gap.csv))\n");
    }
    let _ = writeln!(s, "![Monte Carlo histograms](mc/histograms.svg)\n");
    let _ = writeln!(s, "![trajectories flown by the policy](mc/trajectories.svg)\n");
    let _ = writeln!(
        s,
        "Per-episode figures: [mc.csv](mc/mc.csv); summary: [summary.json](mc/summary.json).\n"
    );
    export_section(
        &mut s,
        &job.export,
        &job.sil,
        &config.family.family.body.units(),
        &job.model,
    );
    let _ = writeln!(
        s,
        "## The controller, ready to ship\n\n[model/](model/card.md): the flown actor (actor.safetensors), both blobs and the model card, bound by their CRC-32C. Copy the folder to `models/NAME/`; `ground model evaluate --model` and `ground model sil --model` fly it as it is.\n"
    );
    note_missing_figures(&s, run)
}

/// The rounds' table and figures; `folder` is their folder relative to the report.
fn rounds_section(s: &mut String, rounds: &DaggerSummary, folder: &str) {
    let _ = writeln!(
        s,
        "Each round flies the policy, re-solves the optimal rest of the flights that miss the most from the states they visited, adds those tuples to the demonstrations and updates (docs/design/learning.md). The round scoring best is kept: round {} of {}. The rounds stopped there: {}.\n",
        rounds.best_round,
        rounds.rows.last().map_or(0, |r| r.round),
        rounds.stopped
    );
    let _ = writeln!(
        s,
        "| round | relabels converged | within the goal (scoring) | dr p50 / p95 (AU) | dv p50 / p95 | s |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    for r in &rounds.rows {
        let _ = writeln!(
            s,
            "| {} | {} / {} | {:.1} % | {:.4} / {:.4} | {:.4} / {:.4} | {:.0} |",
            r.round,
            r.relabels_converged,
            r.relabels_attempted,
            100.0 * r.within_goal,
            r.summary.terminal_position.p50,
            r.summary.terminal_position.p95,
            r.summary.terminal_velocity.p50,
            r.summary.terminal_velocity.p95,
            r.seconds
        );
    }
    let _ = writeln!(s, "\nPer-round figures: [rounds.csv]({folder}/rounds.csv).\n");
    let _ = writeln!(s, "![relabelling rounds]({folder}/rounds.svg)\n");
}

fn export_section(
    s: &mut String,
    export: &ExportReport,
    sil: &[SilReport; 2],
    units: &shared::mission::Units,
    card: &ModelCard,
) {
    let _ = writeln!(s, "## Onboard blobs and software-in-the-loop flight\n");
    let _ = writeln!(
        s,
        "The best model's actor mean network as onboard weight blobs ([export.json](export/export.json)); action error against the trained (tch) actor on {} held-out states; int8 activation scales calibrated on {} states ({} of them demonstrations). Closed loop: the blob flown by the onboard crate in the ground environment on the {} Monte Carlo scenarios.\n",
        export.held_out_states, export.calibration_states, export.demonstration_states, export.closed_loop_episodes
    );
    let _ = writeln!(
        s,
        "| blob | bytes | action error p50 / p95 / max | closed-loop reward | dr p50 (AU) |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|");
    for b in [&export.f32, &export.int8] {
        let name = b
            .file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let _ = writeln!(
            s,
            "| [{name}](export/{name}) | {} | {:.1e} / {:.1e} / {:.1e} | {:.4} | {:.4} |",
            b.bytes,
            b.action_error.p50,
            b.action_error.p95,
            b.action_error.max,
            b.closed_loop.total_reward.mean,
            b.closed_loop.terminal_position.p50
        );
    }
    let _ = writeln!(
        s,
        "\nThe int8 blob's closed-loop mean reward differs from the f32 blob's by {:.2} % (the goal: at most 2 %).\n",
        100.0 * export.int8_reward_difference
    );
    let failed = export.failed_criteria();
    if !failed.is_empty() {
        let _ = writeln!(
            s,
            "**The export check failed** (`ground model export` exits non-zero on it): {}.\n",
            failed.join("; ")
        );
    }
    let d = &sil[0].dispersions;
    let _ = writeln!(
        s,
        "**SIL with dispersions** (the onboard guidance loop against the truth plant, 1 sigma): navigation {:.0} km / {:.2} m/s per axis, thrust magnitude {:.1} % (per flight), pointing {:.2} deg, {} missed-thrust events of {} days per year.\n",
        d.navigation_position * units.length_m / 1e3,
        d.navigation_velocity * units.velocity_m_s(),
        100.0 * d.thrust_magnitude,
        d.pointing.to_degrees(),
        d.missed_thrust_per_year,
        d.missed_thrust_days
    );
    if let Some(t) = sil[0].terminal {
        let _ = writeln!(
            s,
            "The blobs fly their last {} cycles with terminal targeting (`onboard::terminal`).\n",
            t.cycles
        );
    }
    let _ = writeln!(
        s,
        "| blob | flights | within the goal | reward | final mass | dr p50 | dr p95 | dv p50 | guidance faults | missed thrust |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|");
    for (r, folder) in sil.iter().zip(crate::sil::SIL_FOLDERS) {
        let p = &r.monte_carlo.policy;
        let _ = writeln!(
            s,
            "| {} ([summary]({folder}/sil.json)) | {}/{} | {:.1} % | {:.4} ± {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {} | {:.1} % |",
            r.controller,
            p.completed,
            r.flights,
            100.0 * r.monte_carlo.within_accuracy_goal,
            p.total_reward.mean,
            p.total_reward.std,
            p.final_mass.mean,
            p.terminal_position.p50,
            p.terminal_position.p95,
            p.terminal_velocity.p50,
            r.guidance_faults,
            100.0 * r.missed_thrust_fraction
        );
    }
    if let Some(bands) = missed_thrust_bands(&sil[0].by_last_missed_thrust) {
        let _ = writeln!(
            s,
            "\nWithin the goal (f32) by where a flight's last missed thrust ended, as a fraction of the flight (flights): {bands}."
        );
    }
    s.push('\n');
    flown_section(s, card);
    let _ = writeln!(s, "![SIL histograms, int8](sil-int8/histograms.svg)\n");
    let _ = writeln!(s, "![SIL flights, int8](sil-int8/trajectories.svg)\n");
}

/// The controller as it flies, where the Monte Carlo above is the network alone: the card's
/// nominal Monte Carlo of the f32 blob with its onboard aids, when the config flies any.
fn flown_section(s: &mut String, card: &ModelCard) {
    let Some(flown) = card.as_flown() else {
        return;
    };
    let what = crate::model::aids_flown(card);
    let mc = &flown.monte_carlo;
    let shares: Vec<String> = mc
        .within
        .iter()
        .map(|(t, share)| format!("{:.1} % within {t}", 100.0 * share))
        .collect();
    let overspend = flown.overspend.map_or(String::new(), |(n, p50, _)| {
        format!("; propellant overspend median {:.1} % ({n} scenarios)", 100.0 * p50)
    });
    let _ = writeln!(
        s,
        "**As flown**: the f32 blob with {what}, on the Monte Carlo's {} scenarios without dispersions ([summary]({}/sil.json)): {}; dr p50 / p95 {:.4} / {:.4} AU, dv p50 / p95 {:.4} / {:.4}; final mass {:.4}{overspend}.\n",
        mc.episodes,
        crate::sil::AIDED_FOLDER,
        shares.join(", "),
        mc.dr_p50,
        mc.dr_p95,
        mc.dv_p50,
        mc.dv_p95,
        mc.final_mass_mean
    );
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

#[cfg(test)]
mod tests {
    use super::*;

    fn shipped_card(name: &str) -> ModelCard {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../models/{name}/card.json"));
        serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap()
    }

    /// The report's as-flown line reads the card's own figures and names the aids flown, and a
    /// card of the network alone has none.
    #[test]
    fn the_as_flown_line_gives_the_cards_figures_and_aids() {
        let mut card = shipped_card("venus-inward");
        let flown = card.with_terminal.clone().unwrap();
        let mut s = String::new();
        flown_section(&mut s, &card);
        assert!(
            s.starts_with("**As flown**: the f32 blob with terminal targeting of the last 8 cycles"),
            "{s}"
        );
        for (tolerance, share) in &flown.monte_carlo.within {
            assert!(s.contains(&format!("{:.1} % within {tolerance}", 100.0 * share)), "{s}");
        }
        assert!(s.contains(&format!("({}/sil.json)", crate::sil::AIDED_FOLDER)), "{s}");
        card.with_terminal = None;
        card.terminal = None;
        let mut none = String::new();
        flown_section(&mut none, &card);
        assert!(none.is_empty(), "{none}");
    }
}
