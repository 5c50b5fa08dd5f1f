//! Scenarios and tolerances the shooting tests share.

use onboard::integrator::Tolerances;
use shared::orbit::{OrbitElements, OrbitShape};
use shared::scenario::Scenario;

/// The integration accuracy every shooting test uses (docs/spec.md: rtol 1e-11 or tighter).
pub(super) fn tight() -> Tolerances {
    Tolerances {
        relative: 1e-12,
        absolute: 1e-13,
        ..Tolerances::default()
    }
}

/// Final mass of the impulsive Hohmann transfer between circular orbits r1 -> r2: the
/// upper bound of any finite-thrust transfer's final mass.
pub(super) fn hohmann_mass_bound(r1: f64, r2: f64, exhaust_speed: f64) -> f64 {
    let dv = (1.0 / r1).sqrt() * ((2.0 * r2 / (r1 + r2)).sqrt() - 1.0)
        + (1.0 / r2).sqrt() * (1.0 - (2.0 * r1 / (r1 + r2)).sqrt());
    (-dv / exhaust_speed).exp()
}

pub(super) fn circular_scenario(a0: f64, af: f64) -> Scenario {
    let initial = OrbitElements {
        shape: OrbitShape {
            a: a0,
            e: 1e-4,
            omega: 0.0,
        },
        nu: 0.0,
    };
    let target = OrbitShape {
        a: af,
        e: 1e-4,
        omega: 0.0,
    };
    Scenario::transfer(initial, target)
}
