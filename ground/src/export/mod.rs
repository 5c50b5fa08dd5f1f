//! Export of trajectories and policies to formats other tools read: CCSDS OEM ([`oem`]) and
//! the onboard weight blobs ([`policy`]).

pub mod oem;
pub mod policy;
