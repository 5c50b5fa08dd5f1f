//! Spacecraft parameters (docs/spec.md section 1). A parameter of every run, never a constant in
//! code.

use serde::{Deserialize, Serialize};

use crate::mission::Units;
use crate::units::G0_M_S2;

/// Physical spacecraft description in SI units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Spacecraft {
    /// Maximum thrust, N.
    pub max_thrust_n: f64,
    /// Specific impulse, s.
    pub isp_s: f64,
    /// Initial (wet) mass, kg: the mass unit.
    pub initial_mass_kg: f64,
}

/// Why a spacecraft description is unusable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpacecraftError {
    /// Thrust is not finite or not positive.
    Thrust,
    /// Specific impulse is not finite or not positive.
    SpecificImpulse,
    /// Mass is not finite or not positive.
    Mass,
}

impl core::fmt::Display for SpacecraftError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let what = match self {
            Self::Thrust => "maximum thrust must be finite and > 0 N",
            Self::SpecificImpulse => "specific impulse must be finite and > 0 s",
            Self::Mass => "initial mass must be finite and > 0 kg",
        };
        f.write_str(what)
    }
}

impl core::error::Error for SpacecraftError {}

/// The spacecraft in canonical units, as the dynamics use it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CanonicalSpacecraft {
    /// Maximum thrust divided by the initial mass, in AU / t*^2 (so acceleration = T u / m).
    pub thrust: f64,
    /// Exhaust speed Isp g0 in AU / t*.
    pub exhaust_speed: f64,
}

impl Spacecraft {
    /// Mars Sample Return Earth Return Orbiter (thesis Table 4.1).
    pub const MSR_ERO: Self = Self {
        max_thrust_n: 1.33,
        isp_s: 3872.0,
        initial_mass_kg: 3366.0,
    };

    /// Checks the description and converts it to the thesis's heliocentric canonical units.
    pub fn canonical(&self) -> Result<CanonicalSpacecraft, SpacecraftError> {
        self.canonical_in(&Units::HELIOCENTRIC)
    }

    /// Checks the description and converts it to the canonical `units` of a central body.
    pub fn canonical_in(&self, units: &Units) -> Result<CanonicalSpacecraft, SpacecraftError> {
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if !positive(self.max_thrust_n) {
            return Err(SpacecraftError::Thrust);
        }
        if !positive(self.isp_s) {
            return Err(SpacecraftError::SpecificImpulse);
        }
        if !positive(self.initial_mass_kg) {
            return Err(SpacecraftError::Mass);
        }
        Ok(CanonicalSpacecraft {
            thrust: self.max_thrust_n / self.initial_mass_kg / units.acceleration_m_s2(),
            exhaust_speed: self.isp_s * G0_M_S2 / units.velocity_m_s(),
        })
    }
}

impl Default for Spacecraft {
    fn default() -> Self {
        Self::MSR_ERO
    }
}

impl CanonicalSpacecraft {
    /// True when both figures are finite and positive (the dynamics refuse anything else).
    pub fn is_valid(&self) -> bool {
        self.thrust.is_finite() && self.thrust > 0.0 && self.exhaust_speed.is_finite() && self.exhaust_speed > 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn msr_ero_matches_spec_canonical_values() {
        let c = Spacecraft::MSR_ERO.canonical().unwrap();
        assert!((c.thrust - 0.066_631_1).abs() < 1e-7, "T = {}", c.thrust);
        assert!((c.exhaust_speed - 1.274_861_2).abs() < 1e-7, "c = {}", c.exhaust_speed);
    }

    #[test]
    fn refuses_non_physical_parameters() {
        let mut s = Spacecraft::MSR_ERO;
        s.max_thrust_n = 0.0;
        assert_eq!(s.canonical(), Err(SpacecraftError::Thrust));
        let mut s = Spacecraft::MSR_ERO;
        s.isp_s = f64::NAN;
        assert_eq!(s.canonical(), Err(SpacecraftError::SpecificImpulse));
        let mut s = Spacecraft::MSR_ERO;
        s.initial_mass_kg = -1.0;
        assert_eq!(s.canonical(), Err(SpacecraftError::Mass));
    }
}
