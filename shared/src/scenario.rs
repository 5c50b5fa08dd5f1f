//! Scenario types (docs/spec.md section 4): what a transfer or rendezvous problem is. The
//! distributions are defined once here and used by both the data generator and the MDP reset.

use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use crate::orbit::{OrbitElements, OrbitError, OrbitShape};
use crate::units::STEP;

/// Which optimal-control / MDP problem: free-anomaly transfer (TBT) or rendezvous (TBR).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum ProblemKind {
    /// Free-anomaly transfer (TBT, docs/spec.md section 5): reach the target orbit, anywhere on it.
    Transfer,
    /// Rendezvous (TBR, docs/spec.md section 6): meet a body moving on the target orbit.
    Rendezvous,
}

/// The four scenario distributions of docs/spec.md section 4.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ScenarioKind {
    // Aliases: manifests written before the kebab-case names still load.
    /// Transfers between near-circular coplanar orbits of 1 to 1.52 AU (thesis Tables 4.1, 4.3).
    #[serde(alias = "TransferCircular")]
    TransferCircular,
    /// Transfers between eccentric, rotated orbits of 0.39 to 1.52 AU (thesis Table 4.2).
    #[serde(alias = "TransferHard")]
    TransferHard,
    /// Rendezvous between near-circular orbits of 1 to 1.52 AU (thesis Table 4.5).
    #[serde(alias = "RendezvousCircular")]
    RendezvousCircular,
    /// Rendezvous between eccentric, rotated orbits of 0.39 to 1.52 AU (thesis Fig. 7.2).
    #[serde(alias = "RendezvousHard")]
    RendezvousHard,
}

impl ScenarioKind {
    /// Every distribution, in the order of docs/spec.md section 4.
    pub const ALL: [Self; 4] = [
        Self::TransferCircular,
        Self::TransferHard,
        Self::RendezvousCircular,
        Self::RendezvousHard,
    ];

    /// The CLI / config name, e.g. `transfer-circular`.
    pub fn name(self) -> &'static str {
        match self {
            Self::TransferCircular => "transfer-circular",
            Self::TransferHard => "transfer-hard",
            Self::RendezvousCircular => "rendezvous-circular",
            Self::RendezvousHard => "rendezvous-hard",
        }
    }

    /// The problem the distribution's scenarios pose.
    pub fn problem(self) -> ProblemKind {
        match self {
            Self::TransferCircular | Self::TransferHard => ProblemKind::Transfer,
            Self::RendezvousCircular | Self::RendezvousHard => ProblemKind::Rendezvous,
        }
    }
}

/// Closed interval [lo, hi] a parameter is drawn from uniformly (lo == hi: fixed).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Range {
    /// Lower bound.
    pub lo: f64,
    /// Upper bound.
    pub hi: f64,
}

/// The parameter ranges of a scenario distribution (docs/spec.md section 4 table). Both orbits
/// share them; angles in radians.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ScenarioRanges {
    /// Semi-major axis (AU), both orbits.
    pub a: Range,
    /// Eccentricity, both orbits.
    pub e: Range,
    /// Argument of periapsis (rad), both orbits.
    pub omega: Range,
    /// Initial anomaly nu0 and, for rendezvous, the target's nuf0.
    pub nu: Range,
}

const TWO_PI: f64 = 2.0 * core::f64::consts::PI;

impl ScenarioKind {
    /// The docs/spec.md section 4 ranges.
    pub fn ranges(self) -> ScenarioRanges {
        let full = Range { lo: 0.0, hi: TWO_PI };
        match self {
            Self::TransferCircular | Self::RendezvousCircular => ScenarioRanges {
                a: Range { lo: 1.0, hi: 1.52 },
                e: Range { lo: 1e-4, hi: 1e-4 },
                omega: Range { lo: 0.0, hi: 0.0 },
                nu: full,
            },
            Self::TransferHard | Self::RendezvousHard => ScenarioRanges {
                a: Range { lo: 0.39, hi: 1.52 },
                e: Range { lo: 1e-4, hi: 0.75 },
                omega: full,
                nu: full,
            },
        }
    }

    /// Draws scenario number `index` of the stream `seed`. Each index has its own ChaCha8
    /// stream, so any shard of a dataset regenerates alone and identically.
    pub fn draw(self, seed: u64, index: u64) -> Scenario {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(index);
        let ranges = self.ranges();
        // Always eight draws in this order, whatever is fixed, so the layout never shifts.
        let mut uniform = |range: Range| {
            let unit = (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
            range.lo + (range.hi - range.lo) * unit
        };
        let initial = OrbitElements {
            shape: OrbitShape {
                a: uniform(ranges.a),
                e: uniform(ranges.e),
                omega: uniform(ranges.omega),
            },
            nu: uniform(ranges.nu),
        };
        let target = OrbitShape {
            a: uniform(ranges.a),
            e: uniform(ranges.e),
            omega: uniform(ranges.omega),
        };
        let target_nu0 = uniform(ranges.nu);
        Scenario {
            problem: self.problem(),
            initial,
            target,
            target_nu0,
            steps: Scenario::steps_for(&initial.shape, &target),
        }
    }
}

/// One concrete problem: where the spacecraft starts, where it must go, and in how many
/// 14-day steps.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Scenario {
    /// Transfer or rendezvous.
    pub problem: ProblemKind,
    /// Departure orbit and anomaly at t = 0; the spacecraft starts there with m = 1.
    pub initial: OrbitElements,
    /// Target orbit. For a transfer any anomaly on it will do.
    pub target: OrbitShape,
    /// Rendezvous only: the target body's true anomaly at t = 0 (rad). Ignored for transfers.
    pub target_nu0: f64,
    /// Number of 14-day steps N; the time of flight is N * STEP.
    pub steps: u32,
}

impl Scenario {
    /// A transfer from `initial` to any point of `target`, with the docs/spec.md section 4 time of
    /// flight.
    pub fn transfer(initial: OrbitElements, target: OrbitShape) -> Self {
        Self {
            problem: ProblemKind::Transfer,
            initial,
            target,
            target_nu0: 0.0,
            steps: Self::steps_for(&initial.shape, &target),
        }
    }

    /// Time of flight in t*.
    pub fn time_of_flight(&self) -> f64 {
        f64::from(self.steps) * STEP
    }

    /// The docs/spec.md section 4 rule: TOF = max(P0, Pf) rounded up to whole steps.
    pub fn steps_for(initial: &OrbitShape, target: &OrbitShape) -> u32 {
        let tof = libm::fmax(initial.period(), target.period());
        // Saturating float->int conversion: absurd periods cannot wrap around.
        libm::ceil(tof / STEP - 1e-12) as u32
    }

    /// Checks every number of the scenario.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        self.initial.validate().map_err(ScenarioError::Initial)?;
        self.target.validate().map_err(ScenarioError::Target)?;
        if self.problem == ProblemKind::Rendezvous && !self.target_nu0.is_finite() {
            return Err(ScenarioError::Target(OrbitError::Angle));
        }
        if self.steps == 0 {
            return Err(ScenarioError::TimeOfFlight);
        }
        Ok(())
    }
}

impl core::str::FromStr for ScenarioKind {
    type Err = UnknownScenarioKind;

    /// The distribution of a CLI / config name ([`ScenarioKind::name`]).
    fn from_str(name: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or(UnknownScenarioKind)
    }
}

/// A name that is none of [`ScenarioKind::ALL`]'s.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnknownScenarioKind;

impl core::fmt::Display for UnknownScenarioKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("unknown scenario kind, expected one of:")?;
        for (i, kind) in ScenarioKind::ALL.iter().enumerate() {
            f.write_str(if i == 0 { " " } else { ", " })?;
            f.write_str(kind.name())?;
        }
        Ok(())
    }
}

impl core::error::Error for UnknownScenarioKind {}

/// Why a scenario is unusable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScenarioError {
    /// The departure orbit is unusable.
    Initial(OrbitError),
    /// The target orbit is unusable.
    Target(OrbitError),
    /// The time of flight must be at least one step.
    TimeOfFlight,
}

impl core::fmt::Display for ScenarioError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Initial(e) => write!(f, "initial orbit: {e}"),
            Self::Target(e) => write!(f, "target orbit: {e}"),
            Self::TimeOfFlight => f.write_str("time of flight must be at least one 14-day step"),
        }
    }
}

impl core::error::Error for ScenarioError {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_name_parses_back_to_its_kind_and_others_are_refused() {
        for kind in ScenarioKind::ALL {
            assert_eq!(kind.name().parse::<ScenarioKind>(), Ok(kind));
        }
        for bad in [
            "",
            "transfer",
            "Transfer-Circular",
            "transfer-circular ",
            "transfer-easy",
        ] {
            assert_eq!(bad.parse::<ScenarioKind>(), Err(UnknownScenarioKind));
        }
    }

    #[test]
    fn draws_are_reproducible_independent_per_index_and_inside_the_ranges() {
        for kind in ScenarioKind::ALL {
            let r = kind.ranges();
            let inside = |x: f64, range: Range| x >= range.lo && x <= range.hi;
            for index in 0..200 {
                let s = kind.draw(42, index);
                assert_eq!(s, kind.draw(42, index));
                assert_ne!(s, kind.draw(43, index));
                assert_ne!(s, kind.draw(42, index + 1));
                assert_eq!(s.problem, kind.problem());
                assert!(s.validate().is_ok());
                for shape in [s.initial.shape, s.target] {
                    assert!(inside(shape.a, r.a) && inside(shape.e, r.e) && inside(shape.omega, r.omega));
                }
                assert!(inside(s.initial.nu, r.nu) && inside(s.target_nu0, r.nu));
                assert_eq!(s.steps, Scenario::steps_for(&s.initial.shape, &s.target));
            }
        }
    }

    #[test]
    fn draws_cover_the_range_uniformly() {
        // Mean and variance of 4000 draws of a0 against those of U(1, 1.52): 5-sigma bounds.
        let n = 4000;
        let xs: [f64; 4000] =
            core::array::from_fn(|i| ScenarioKind::TransferCircular.draw(7, i as u64).initial.shape.a);
        let mean = xs.iter().sum::<f64>() / f64::from(n);
        let var = xs.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / f64::from(n);
        let (w, m) = (0.52, 1.26);
        let sd_mean = w / libm::sqrt(12.0 * f64::from(n));
        assert!((mean - m).abs() < 5.0 * sd_mean, "mean {mean}");
        assert!((var - w * w / 12.0).abs() < 0.1 * w * w / 12.0, "var {var}");
    }

    #[test]
    fn time_of_flight_rounds_the_longer_period_up_to_whole_steps() {
        let earth = OrbitShape {
            a: 1.0,
            e: 1e-4,
            omega: 0.0,
        };
        let mars = OrbitShape {
            a: 1.52,
            e: 1e-4,
            omega: 0.0,
        };
        let n = Scenario::steps_for(&earth, &mars);
        let p = mars.period();
        assert!(f64::from(n) * STEP >= p && f64::from(n - 1) * STEP < p);
        // 1.52 AU: 684.5 days -> 49 steps of 14 days (686 days).
        assert_eq!(n, 49);
        assert_eq!(Scenario::steps_for(&earth, &earth), 27);
    }
}
