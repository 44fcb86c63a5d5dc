//! Light sources: the octahedral HDR environment map ([`envmap`]) and the procedural maps
//! the built-in scenes use ([`procedural`]).

pub mod envmap;
pub mod procedural;

pub use envmap::{EnvMap, ExrLayout};
