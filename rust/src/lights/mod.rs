//! Light sources: the octahedral HDR environment map ([`envmap`], over batches of rows in
//! [`envmap::rows`]), the procedural maps the built-in scenes use ([`procedural`]) and area
//! lights made of triangles ([`area`]), and sets of virtual point lights ([`vpl`]; the light
//! paths that deposit them are traced by `estimators::many_lights::light_paths`).

pub mod area;
pub mod envmap;
pub mod procedural;
pub mod vpl;

pub use area::AreaLight;
pub use envmap::{EnvMap, ExrLayout};

/// Largest radiance (W/(m² sr), any channel) a light may have. Estimates and their
/// variances come out as `f32`: a sample of radiance `L` contributes `L f / p`, whose square
/// must stay below `f32::MAX` (3.4e38) with room for pdf ratios of 1e8. The sun of a
/// physical sky is about 1e9.
pub const MAX_RADIANCE: f32 = 1e15;

/// True when every channel is finite and in `[0, MAX_RADIANCE]`.
pub fn valid_radiance(v: [f32; 3]) -> bool {
    v.iter().all(|c| (0.0..=MAX_RADIANCE).contains(c))
}

/// What is wrong with a radiance that is not [`valid_radiance`], for error messages.
pub fn radiance_problem(v: [f32; 3]) -> String {
    format!(
        "must be finite and in [0, {MAX_RADIANCE:e}] per channel (larger values overflow the \
         f32 estimates and variances: rescale), got {v:?}"
    )
}
