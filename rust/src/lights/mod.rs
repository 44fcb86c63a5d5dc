//! Light sources: the octahedral HDR environment map ([`envmap`]), the procedural maps the
//! built-in scenes use ([`procedural`]) and area lights made of triangles ([`area`]).

pub mod area;
pub mod envmap;
pub mod procedural;

pub use area::AreaLight;
pub use envmap::{EnvMap, ExrLayout};
