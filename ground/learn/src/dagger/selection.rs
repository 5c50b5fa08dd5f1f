//! Which flights a round relabels (the largest misses, or the probes that re-solve), and the
//! score that picks the best round.

use crate::config::ExperimentConfig;
use crate::error::ExperimentError;
use crate::eval::{within_accuracy_goal, ACCURACY_GOAL};
use crate::phase::{evaluate_agent, family_of};
use crate::sac::agent::Sac;
use crate::sil::{SilFlights, SilGeometry};
use ground_core::env::batch::{summarize, EpisodeOutcome, OutcomeSummary};
use ground_core::env::{Geometry, MdpEnv, Problem};

/// The `count` outcomes that miss the accuracy goal the most, max(dr, dv) / [`ACCURACY_GOAL`]
/// (the earlier of equal misses first), returned in episode order. Fewer outcomes than `count`:
/// all of them.
pub(crate) fn largest_misses<G: Geometry>(outcomes: Vec<&EpisodeOutcome<G>>, count: usize) -> Vec<&EpisodeOutcome<G>> {
    if outcomes.len() <= count {
        return outcomes;
    }
    let mut largest = ranked_by_miss(outcomes);
    largest.truncate(count);
    largest.sort_by_key(|o| o.episode);
    largest
}

/// The outcomes from the largest miss of the accuracy goal to the smallest, max(dr, dv) /
/// [`ACCURACY_GOAL`], the earlier of equal misses first.
pub(crate) fn ranked_by_miss<G: Geometry>(mut outcomes: Vec<&EpisodeOutcome<G>>) -> Vec<&EpisodeOutcome<G>> {
    outcomes.sort_by(|a, b| miss(b).total_cmp(&miss(a)).then(a.episode.cmp(&b.episode)));
    outcomes
}

/// A flight's miss in units of the accuracy goal: max(dr, dv) / [`ACCURACY_GOAL`].
fn miss<G: Geometry>(outcome: &EpisodeOutcome<G>) -> f64 {
    outcome.terminal.position.max(outcome.terminal.velocity) / ACCURACY_GOAL
}

/// The flights a round may relabel, in episode order: completed, with a step strictly inside
/// the flight, and missing by at most `max_miss` times the goal when that is set.
pub(crate) fn relabel_candidates<'a, G: Geometry>(
    flown: &'a [EpisodeOutcome<G>],
    scenarios: &[G::Scenario],
    max_miss: Option<f64>,
) -> Vec<&'a EpisodeOutcome<G>> {
    flown
        .iter()
        .filter(|o| o.completed && G::plan(&scenarios[o.episode]).steps >= 2)
        .filter(|o| max_miss.is_none_or(|cap| miss(o) <= cap))
        .collect()
}

/// Flights probed at once by [`walk_probes`]: enough to keep every core busy, few enough that
/// the probes past the quota waste little.
const PROBE_CHUNK: usize = 32;

/// Probes `ranked` in order, [`PROBE_CHUNK`] at a time (`probe` takes a chunk and answers for
/// each item, in order), until at least `quota` probes have succeeded (every success of the last
/// chunk is kept, so the result does not depend on how a chunk is solved). Returns the successes
/// in rank order and how many were probed.
pub(crate) fn walk_probes<T, E>(
    ranked: &[usize],
    quota: usize,
    mut probe: impl FnMut(&[usize]) -> Result<Vec<Option<T>>, E>,
) -> Result<(Vec<(usize, T)>, usize), E> {
    let mut kept = Vec::new();
    let mut probed = 0;
    for chunk in ranked.chunks(PROBE_CHUNK) {
        if kept.len() >= quota {
            break;
        }
        let results = probe(chunk)?;
        probed += chunk.len();
        kept.extend(chunk.iter().zip(results).filter_map(|(&item, r)| r.map(|t| (item, t))));
    }
    Ok((kept, probed))
}

/// A round's score on the evaluation seed's first `dagger.score_episodes` scenarios.
pub(crate) struct Score {
    pub(crate) within_goal: f64,
    pub(crate) summary: OutcomeSummary,
    /// The share within the goal of the onboard f32 controller with the SIL's dispersions
    /// (`dagger.dispersed`).
    pub(crate) within_goal_dispersed: Option<f64>,
}

/// Scores the learner on the evaluation seed's first `dagger.score_episodes` scenarios, and
/// under the SIL's dispersions when the rounds relabel dispersed flights.
pub(crate) fn score<P: Problem>(config: &ExperimentConfig, agent: &Sac) -> Result<Score, ExperimentError>
where
    P::Geometry: SilGeometry,
{
    let family = family_of::<P::Geometry>(config)?;
    let outcomes = evaluate_agent::<MdpEnv<P>>(
        agent,
        &config.env,
        family,
        config.seeds.evaluation,
        config.dagger.score_episodes,
        false,
    )?;
    let within_goal_dispersed = if config.dagger.dispersed {
        let scenarios: Vec<_> = (0..config.dagger.score_episodes)
            .map(|i| P::Geometry::draw(&family, config.seeds.evaluation, i))
            .collect();
        let flights = SilFlights::network_alone(&config.sil.dispersions, config.seeds.evaluation);
        let flown = P::Geometry::fly_learner(config, agent, &scenarios, &flights)?;
        Some(within_accuracy_goal(&flown))
    } else {
        None
    };
    Ok(Score {
        within_goal: within_accuracy_goal(&outcomes),
        summary: summarize(&outcomes),
        within_goal_dispersed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use onboard::features::Residuals;
    use shared::scenario::Scenario;

    fn outcome(episode: usize, dr: f64, dv: f64) -> EpisodeOutcome {
        EpisodeOutcome {
            episode,
            total_reward: 0.0,
            final_mass: 1.0,
            terminal: Residuals {
                position: dr,
                velocity: dv,
            },
            steps: 10,
            completed: true,
            error: None,
            non_finite_actions: 0,
            trajectory: None,
        }
    }

    #[test]
    fn the_relabelled_episodes_are_the_largest_misses_in_episode_order() {
        // Misses in goal units: 0.5, 3 (velocity), 2, 0.1, 2 (tie with 2: the earlier wins), 4.
        let flown = [
            outcome(0, 0.005, 0.001),
            outcome(1, 0.002, 0.03),
            outcome(2, 0.02, 0.0),
            outcome(3, 0.001, 0.001),
            outcome(4, 0.0, 0.02),
            outcome(5, 0.04, 0.04),
        ];
        let chosen = |count| -> Vec<usize> {
            largest_misses(flown.iter().collect(), count)
                .iter()
                .map(|o| o.episode)
                .collect()
        };
        assert_eq!(chosen(3), vec![1, 2, 5]);
        assert_eq!(chosen(4), vec![1, 2, 4, 5]);
        // As many as flown (the default: candidates = episodes): every one, in order.
        assert_eq!(chosen(6), vec![0, 1, 2, 3, 4, 5]);
        assert_eq!(chosen(9), vec![0, 1, 2, 3, 4, 5]);
    }

    #[test]
    fn flights_beyond_the_miss_cap_are_not_relabelled() {
        let scenarios: Vec<Scenario> = (0..5)
            .map(|i| shared::scenario::ScenarioKind::TransferHard.draw(3, i))
            .collect();
        let mut flown = vec![
            outcome(0, 0.005, 0.001),
            outcome(1, 0.2, 0.0),
            outcome(2, 0.0, 0.1),
            outcome(3, 0.1000001, 0.0),
            outcome(4, 0.5, 0.5),
        ];
        let kept = |flown: &[EpisodeOutcome], cap| -> Vec<usize> {
            relabel_candidates(flown, &scenarios, cap)
                .iter()
                .map(|o| o.episode)
                .collect()
        };
        assert_eq!(kept(&flown, None), vec![0, 1, 2, 3, 4]);
        // 10 times the goal: 0.1 AU or 0.1, inclusive.
        assert_eq!(kept(&flown, Some(10.0)), vec![0, 2]);
        assert_eq!(kept(&flown, Some(20.0)), vec![0, 1, 2, 3]);
        flown[0].completed = false;
        assert_eq!(kept(&flown, Some(20.0)), vec![1, 2, 3]);
    }

    #[test]
    fn probes_walk_the_ranking_in_chunks_until_the_quota_and_keep_the_last_chunk_whole() {
        // Items ranked 0..100; the probe succeeds on multiples of 3 and reports its item.
        let ranked: Vec<usize> = (0..100).collect();
        let probe = |chunk: &[usize]| -> Result<Vec<Option<usize>>, ()> {
            Ok(chunk
                .iter()
                .map(|&item| item.is_multiple_of(3).then_some(item * 10))
                .collect())
        };
        // 11 successes in the first chunk (0..32): a quota of 5 stops there, all 11 kept.
        let (kept, probed) = walk_probes(&ranked, 5, probe).unwrap();
        assert_eq!(probed, PROBE_CHUNK);
        assert_eq!(kept.len(), 11);
        assert!(kept.iter().all(|&(item, t)| item.is_multiple_of(3) && t == item * 10));
        assert!(kept.windows(2).all(|w| w[0].0 < w[1].0), "rank order");
        // A quota of 12 needs the second chunk (32..64: 11 more).
        let (kept, probed) = walk_probes(&ranked, 12, probe).unwrap();
        assert_eq!((kept.len(), probed), (22, 2 * PROBE_CHUNK));
        // More than can succeed: every item probed once.
        let (kept, probed) = walk_probes(&ranked, 1000, probe).unwrap();
        assert_eq!((kept.len(), probed), (34, 100));
        // A ranking that is not in item order is walked in its own order.
        let reversed: Vec<usize> = (0..100).rev().collect();
        let (kept, _) = walk_probes(&reversed, 1, probe).unwrap();
        assert_eq!(kept.first().map(|k| k.0), Some(99));
    }
}
