//! Every error type of the flight code and of the shared contract is a `core::error::Error`
//! (no_std), so a host tool can box it, chain it or report it like any other error.

use core::error::Error;

use onboard::dynamics::{PropagationError, StateError};
use onboard::features::FeatureError;
use onboard::guidance::GuidanceError;
use onboard::integrator::IntegrationError;
use onboard::kepler::KeplerError;
use onboard::policy::PolicyError;
use shared::blob::{BlobError, PayloadError};
use shared::orbit::OrbitError;
use shared::quantize::QuantizeError;
use shared::scenario::ScenarioError;
use shared::spacecraft::SpacecraftError;

fn message<E: Error + 'static>(e: E) -> String {
    let boxed: Box<dyn Error> = Box::new(e);
    boxed.to_string()
}

#[test]
fn every_error_type_is_an_error_with_a_message() {
    let messages = [
        message(PropagationError::State(StateError::ZeroRadius)),
        message(StateError::NonFinite),
        message(FeatureError::TimeToGo),
        message(GuidanceError::NonFiniteAction),
        message(IntegrationError::StepSizeUnderflow { t: 1.5 }),
        message(IntegrationError::InvalidInput),
        message(KeplerError::NoConvergence),
        message(PolicyError::BadScale { layer: 1 }),
        message(BlobError::NoLayers),
        message(PayloadError::BadVarint),
        message(OrbitError::Eccentricity),
        message(QuantizeError::NonFinite { layer: 0 }),
        message(ScenarioError::TimeOfFlight),
        message(SpacecraftError::Mass),
    ];
    for m in &messages {
        assert!(!m.is_empty());
    }
    assert_eq!(messages[4], "step size underflow at t = 1.500000");
}
