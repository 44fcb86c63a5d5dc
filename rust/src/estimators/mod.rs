//! Estimators: direct illumination, indirect illumination by path tracing, the many-light renderer over virtual point lights, lighting preview (CAM08 §6.2) and ambient occlusion
//! from the cache (CAM08 §6.1).

pub mod ambient;
pub mod control_variate;
pub mod decoupled;
pub mod direct;
pub mod importance;
pub mod indirect;
pub mod irradiance;
pub mod many_lights;
pub mod normal_products;
pub mod preview;
pub mod stochastic_visibility;
pub mod vf;
