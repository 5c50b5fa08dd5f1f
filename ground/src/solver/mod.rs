//! The indirect fuel-optimal trajectory solver (SPEC section 3).

pub mod pontryagin;
pub mod shooting;
