//! The controllers shipped under `models/`: every folder opens (its files agree with its card),
//! and its f32 blob, flown by the onboard crate in the SIL loop without dispersions on the first
//! 1,000 of the card's Monte Carlo scenarios, scores the card's share within the accuracy goal.
//! The card's share was measured by the tch actor on all the Monte Carlo's scenarios, so the two
//! are different implementations of the policy on overlapping samples: they must agree within
//! the sampling error of 1,000 flights. Its int8 blob, flown on the same scenarios, scores within
//! a point of the f32 blob (the export's promise), within the paired sampling error. A controller
//! whose card records flying with an onboard aid (rollout lookahead, terminal targeting) scores,
//! flown so on the first scenarios, the card's as-flown share within the sampling error.

use std::path::{Path, PathBuf};

use firmware_sim::Dispersions;
use ground_core::env::batch::EpisodeOutcome;
use ground_core::env::{Planar, Spatial};
use learn::eval::{within_accuracy_goal, ACCURACY_GOAL};
use learn::export::blob_file;
use learn::model::{open_model, ShippedModel};
use learn::sil::{SilFlights, SilGeometry};
use shared::blob::Quantization;

/// Flights per shipped controller.
const FLIGHTS: u64 = 1000;
/// Flights with the onboard aids (with lookahead about 26 times the work of a flight alone).
/// Enough that three standard deviations stay within 5 points of the card's share: transfer-hard's
/// draws differ widely, and its first 300 arrive 8 points below its 10,000 with the aids.
const AIDED_FLIGHTS: u64 = 1000;

/// Three binomial standard deviations of `n` flights around `share`, plus half a point for the
/// flights near the goal's edge that two implementations end on either side of.
fn bound(share: f64, n: u64) -> f64 {
    3.0 * (share * (1.0 - share) / n as f64).sqrt() + 0.005
}

fn shipped_models() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models");
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap_or_else(|e| panic!("{}: {e}", root.display()))
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.is_dir())
        .collect();
    dirs.sort();
    dirs
}

#[test]
fn every_shipped_controller_flies_onboard_as_its_card_says() {
    let dirs = shipped_models();
    assert!(!dirs.is_empty(), "no controller is shipped under models/");
    for dir in dirs {
        let model = open_model(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
        // An inclined family's blobs fly the three-dimensional loop.
        if model.config.is_inclined() {
            flies_as_its_card_says::<Spatial>(&dir, &model);
        } else {
            flies_as_its_card_says::<Planar>(&dir, &model);
        }
    }
}

fn flies_as_its_card_says<G: SilGeometry>(dir: &Path, model: &ShippedModel) {
    let config = &model.config;
    let problem = config.problem();
    let card_share = model
        .card
        .monte_carlo
        .share_within(ACCURACY_GOAL)
        .unwrap_or_else(|| panic!("{}: the card has no share within the goal", dir.display()));
    assert_eq!(model.card.monte_carlo_seed, config.seeds.monte_carlo);
    let blob_path = dir.join(blob_file(problem, Quantization::F32));
    let blob = std::fs::read(&blob_path).unwrap();
    let family = G::family_of(&config.family).unwrap();
    let scenarios: Vec<G::Scenario> = (0..FLIGHTS)
        .map(|i| G::draw(&family, config.seeds.monte_carlo, i))
        .collect();
    let alone = |blob: &[u8]| {
        let flights = SilFlights::network_alone(&Dispersions::NONE, config.seeds.monte_carlo);
        G::fly_blob(config, blob, &scenarios, &flights).unwrap()
    };
    let (outcomes, guidance_faults, _) = alone(&blob);
    assert_eq!(guidance_faults, 0, "{}", dir.display());
    assert!(outcomes.iter().all(|o| o.completed), "{}", dir.display());
    let flown_share = within_accuracy_goal(&outcomes);
    // The 1,000 flights are a subset of the card's episodes (the bound's sampling error is an
    // upper one: the overlap only shrinks the difference).
    assert!(
        (flown_share - card_share).abs() <= bound(card_share, FLIGHTS),
        "{}: flown onboard {:.2} % within the goal, the card says {:.2} %",
        dir.display(),
        100.0 * flown_share,
        100.0 * card_share
    );

    let int8_path = dir.join(blob_file(problem, Quantization::Int8));
    let int8_blob = std::fs::read(&int8_path).unwrap();
    let (int8_outcomes, int8_faults, _) = alone(&int8_blob);
    assert_eq!(int8_faults, 0, "{}", dir.display());
    // Paired flights: only the scenarios that one blob ends within the goal and the other not
    // carry sampling error, so the bound is three standard deviations of their count.
    let inside = |o: &EpisodeOutcome<G>| o.terminal.position <= ACCURACY_GOAL && o.terminal.velocity <= ACCURACY_GOAL;
    let discordant = outcomes
        .iter()
        .zip(&int8_outcomes)
        .filter(|(a, b)| inside(a) != inside(b))
        .count();
    let int8_share = within_accuracy_goal(&int8_outcomes);
    assert!(
        int8_share >= flown_share - 0.01 - 3.0 * (discordant as f64).sqrt() / FLIGHTS as f64,
        "{}: int8 {:.2} % within the goal, f32 {:.2} % ({discordant} flights differ)",
        dir.display(),
        100.0 * int8_share,
        100.0 * flown_share
    );

    // The controller as flown (its config's onboard aids) on the first Monte Carlo scenarios
    // without dispersions: the card's as-flown share.
    if let Some(lookahead) = &model.card.lookahead {
        assert_eq!(config.sil.lookahead, Some(lookahead.settings), "{}", dir.display());
    }
    if model.card.with_terminal.is_some() {
        assert!(config.sil.terminal.is_some(), "{}", dir.display());
    }
    if let Some(flown) = model.card.as_flown() {
        let aid = learn::model::aids_flown(&model.card);
        let card_share = flown.monte_carlo.share_within(ACCURACY_GOAL).unwrap();
        let first = &scenarios[..AIDED_FLIGHTS as usize];
        let flights = SilFlights::of(config, &Dispersions::NONE, 0);
        let (aided, faults, _) = G::fly_blob(config, &blob, first, &flights).unwrap();
        assert_eq!(faults, 0);
        let share = within_accuracy_goal(&aided);
        assert!(
            (share - card_share).abs() <= bound(card_share, AIDED_FLIGHTS),
            "{}: flown with {aid} {:.2} % within the goal, the card says {:.2} %",
            dir.display(),
            100.0 * share,
            100.0 * card_share
        );
    }
}

/// The checkpoint writer is a file format: every shipped actor, loaded and written again, is the
/// same bytes (tensor order, metadata and checksum included).
#[test]
fn every_shipped_actor_written_again_is_the_same_file() {
    let out = std::env::temp_dir().join(format!("lowthrust-actor-rewrite-{}", std::process::id()));
    for dir in shipped_models() {
        let model = open_model(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
        let agent = learn::model::load_actor(&model.config, &model.actor()).unwrap();
        let again = out.join(dir.file_name().unwrap()).join("actor.safetensors");
        agent.save_flown_actor(&again).unwrap();
        assert!(
            std::fs::read(&again).unwrap() == std::fs::read(model.actor()).unwrap(),
            "{}: written again differs",
            dir.display()
        );
    }
    std::fs::remove_dir_all(&out).unwrap();
}
