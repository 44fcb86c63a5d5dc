//! Geometry: triangle meshes, OBJ loading, the BVH and the scene that ties them together.

pub mod bvh;
pub mod huge_pages;
pub mod mesh;
pub mod obj;
pub mod proxies;
pub mod scene;

pub use bvh::{BuildQuality, Bvh, BvhUpdate, Hit, OccluderHint, TraversalCounters};
pub use mesh::{Bounds, Mesh, Object};
pub use scene::{Hits, RayBatch, Scene, SurfaceHit, TMax};
