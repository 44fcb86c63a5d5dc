//! # viscache_rs
//!
//! Monte Carlo direct illumination that exploits how strongly visibility is correlated
//! between nearby points (Clarberg & Akenine-Möller 2008, "CAM08"), with the ray tracing,
//! sampling and scenes it needs. The crate is both a Rust library and, with the `python`
//! feature, the native module `viscache_rs._core`.
//!
//! Data flows one way: [`scenes`] and [`geometry`] build a [`geometry::Scene`] and its BVH,
//! [`camera`] turns a camera into a G-buffer of first hits, [`lights`] holds the environment
//! maps that light them, [`visibility`] holds the visibility cache's records, and the
//! estimators consume them.

pub mod alloc;
pub mod bsdf;
pub mod camera;
pub mod error;
pub mod estimators;
pub mod files;
#[cfg(test)]
mod floors;
pub mod geometry;
pub mod image;
pub mod lights;
pub mod math;
pub mod moments;
pub mod parallel;
pub mod render;
pub mod sampling;
pub mod scenes;
pub mod simd;
pub mod spatial;
pub mod stop;
pub mod testing;
pub mod visibility;

#[cfg(feature = "python")]
mod py;

pub use error::{Error, Result};
