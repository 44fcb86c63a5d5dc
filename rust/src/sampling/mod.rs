//! Sampling: the counter-based random number generator shared by every estimator.

pub mod rng;
