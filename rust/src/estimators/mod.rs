//! Estimators of direct illumination.

pub mod control_variate;
pub mod direct;
pub mod preview;
