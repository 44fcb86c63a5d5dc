//! Estimators of direct illumination, and ambient occlusion from the cache (CAM08 §6.1).

pub mod ambient;
pub mod direct;
