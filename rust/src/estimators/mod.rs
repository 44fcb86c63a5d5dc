//! Estimators of direct illumination.

pub mod direct;
