//! Sampling: the counter-based random number generator, the renderer's per-pixel
//! Owen-scrambled Sobol samples, the equal-area octahedral
//! parameterization of the sphere, hierarchical 2D distributions over it, and the
//! chi-square test every sampler is checked with, the direction pattern of visibility
//! records, and real spherical harmonics (projection and rotation) for the lighting preview.

pub mod chi2;
pub mod distribution;
pub mod octahedral;
pub mod pattern;
pub mod rng;
pub mod sh;
pub mod sobol;
