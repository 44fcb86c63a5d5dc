//! Geometry: triangle meshes, OBJ loading, the BVH and the scene that ties them together.

pub mod binned_sah;
pub mod bvh;
pub mod bvh8;
pub mod huge_pages;
pub mod mesh;
pub mod obj;
pub mod scene;
pub mod watertight;

pub use bvh::{BuildQuality, Bvh, BvhUpdate, Hit, OccluderHint, TraversalCounters};
pub use mesh::{Bounds, Mesh, Object};
pub use scene::{Hits, RayBatch, Scene, SurfaceHit, TMax};
