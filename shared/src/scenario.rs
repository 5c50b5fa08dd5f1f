//! Scenario types (docs/spec.md section 4): what a transfer or rendezvous problem is, and the
//! thesis's four distributions as presets of [`MissionFamily`], used by both the data generator
//! and the MDP reset.

use serde::{Deserialize, Serialize};

use crate::mission::{CentralBody, Cycle, MissionFamily, OrbitRanges, TimeOfFlight};
use crate::orbit::{OrbitElements, OrbitError, OrbitPlane, OrbitShape, SpatialState};
use crate::units::STEP;

/// Which optimal-control / MDP problem: free-anomaly transfer (TBT) or rendezvous (TBR).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum ProblemKind {
    /// Free-anomaly transfer (TBT, docs/spec.md section 5): reach the target orbit, anywhere on it.
    Transfer,
    /// Rendezvous (TBR, docs/spec.md section 6): meet a body moving on the target orbit.
    Rendezvous,
}

/// The four scenario distributions of docs/spec.md section 4: presets of [`MissionFamily`].
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
    pub const fn problem(self) -> ProblemKind {
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

const TWO_PI: f64 = 2.0 * core::f64::consts::PI;

impl ScenarioKind {
    /// The docs/spec.md section 4 ranges, shared by the departure orbit and the target.
    pub const fn ranges(self) -> OrbitRanges {
        let full = Range { lo: 0.0, hi: TWO_PI };
        match self {
            Self::TransferCircular | Self::RendezvousCircular => OrbitRanges {
                a: Range { lo: 1.0, hi: 1.52 },
                e: Range { lo: 1e-4, hi: 1e-4 },
                omega: Range { lo: 0.0, hi: 0.0 },
                nu: full,
            },
            Self::TransferHard | Self::RendezvousHard => OrbitRanges {
                a: Range { lo: 0.39, hi: 1.52 },
                e: Range { lo: 1e-4, hi: 0.75 },
                omega: full,
                nu: full,
            },
        }
    }

    /// The distribution as a family: the Sun in AU, both orbits in [`Self::ranges`], the longer
    /// period rounded up to whole 14-day cycles.
    pub const fn family(self) -> MissionFamily {
        MissionFamily {
            problem: self.problem(),
            body: CentralBody::SUN,
            departure: self.ranges(),
            target: self.ranges(),
            time_of_flight: TimeOfFlight::LongerPeriod,
            cycle: Cycle::Days(14.0),
        }
    }

    /// Draws scenario number `index` of the stream `seed` ([`MissionFamily::draw`]).
    pub fn draw(self, seed: u64, index: u64) -> Scenario {
        self.family().draw(seed, index)
    }
}

/// One concrete problem: where the spacecraft starts, where it must go, and in how many
/// guidance cycles of which length.
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
    /// Number of guidance cycles (environment steps) N; the time of flight is N * cycle.
    pub steps: u32,
    /// Length of one guidance cycle, t* (the thesis's 14 days: [`STEP`]).
    pub cycle: f64,
}

impl Scenario {
    /// A heliocentric transfer from `initial` to any point of `target`, with the docs/spec.md
    /// section 4 time of flight in 14-day cycles.
    pub fn transfer(initial: OrbitElements, target: OrbitShape) -> Self {
        Self {
            problem: ProblemKind::Transfer,
            initial,
            target,
            target_nu0: 0.0,
            steps: Self::steps_for(&initial.shape, &target),
            cycle: STEP,
        }
    }

    /// Time of flight in t*.
    pub fn time_of_flight(&self) -> f64 {
        f64::from(self.steps) * self.cycle
    }

    /// Time from cycle `k`'s start to the arrival, t*.
    pub fn time_to_go(&self, k: u32) -> f64 {
        f64::from(self.steps.saturating_sub(k)) * self.cycle
    }

    /// The start of cycle `k`, t* after departure.
    pub fn cycle_start(&self, k: u32) -> f64 {
        f64::from(k) * self.cycle
    }

    /// The docs/spec.md section 4 rule: TOF = max(P0, Pf) rounded up to whole 14-day steps.
    pub fn steps_for(initial: &OrbitShape, target: &OrbitShape) -> u32 {
        Self::cycles_covering(libm::fmax(initial.period(), target.period()), STEP)
    }

    /// Whole cycles of `cycle` that cover `time_of_flight` (rounded up; a sliver of 1e-12 of a
    /// cycle is rounding).
    pub fn cycles_covering(time_of_flight: f64, cycle: f64) -> u32 {
        // Saturating float->int conversion: absurd times cannot wrap around.
        libm::ceil(time_of_flight / cycle - 1e-12) as u32
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
        if !(self.cycle.is_finite() && self.cycle > 0.0) {
            return Err(ScenarioError::Cycle);
        }
        Ok(())
    }
}

/// A scenario in three dimensions (docs/spec.md section 4, inclined families): a planar [`Scenario`] whose two
/// orbits lie in their own planes. Every figure of `scenario` is measured in its orbit's plane.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SpatialScenario {
    /// The scenario in each orbit's own plane.
    pub scenario: Scenario,
    /// The departure orbit's plane.
    pub initial_plane: OrbitPlane,
    /// The target orbit's plane.
    pub target_plane: OrbitPlane,
}

impl SpatialScenario {
    /// The planar scenario in the reference plane.
    pub const fn planar(scenario: Scenario) -> Self {
        Self {
            scenario,
            initial_plane: OrbitPlane::REFERENCE,
            target_plane: OrbitPlane::REFERENCE,
        }
    }

    /// Whether both orbits lie in the reference plane.
    pub fn is_planar(&self) -> bool {
        self.initial_plane.is_reference() && self.target_plane.is_reference()
    }

    /// The spacecraft's state at departure, inertial.
    pub fn departure(&self) -> SpatialState {
        self.initial_plane.embed(&self.scenario.initial.cartesian())
    }

    /// Checks the planar scenario and both planes.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        self.scenario.validate()?;
        self.initial_plane.validate().map_err(ScenarioError::Initial)?;
        self.target_plane.validate().map_err(ScenarioError::Target)
    }
}

impl From<ScenarioKind> for MissionFamily {
    fn from(kind: ScenarioKind) -> Self {
        kind.family()
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
    /// The time of flight must be at least one cycle.
    TimeOfFlight,
    /// The cycle must be finite and positive.
    Cycle,
}

impl core::fmt::Display for ScenarioError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Initial(e) => write!(f, "initial orbit: {e}"),
            Self::Target(e) => write!(f, "target orbit: {e}"),
            Self::TimeOfFlight => f.write_str("time of flight must be at least one guidance cycle"),
            Self::Cycle => f.write_str("the guidance cycle must be finite and > 0"),
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
                assert_eq!(s.cycle, STEP);
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
