//! Lighting preview (CAM08 §6.2): the control variate's integral `J = ∫ L B~ Ṽ dω` shown
//! directly, an estimate of direct illumination from the exact lighting, the approximate
//! reflectance `B~` and the cache's interpolated visibility `Ṽ`, with no per-pixel
//! sampling.
//!
//! [`LightingPreview::new`] traces the primary rays once and keeps the first hits; every
//! [`LightingPreview::render`] after that — with another environment map, a rotated one,
//! or a cache that has grown — looks the records up again and integrates `J`, but traces
//! no ray at all. Channel `c` is scaled by the material's
//! [`crate::bsdf::Material::channel_ratios`], as in the control variate.

use glam::Vec3;
use rayon::prelude::*;

use super::control_variate::{ControlTables, Interpolant, MapChroma};
use super::direct::{ProductDistribution, ProductLevel};
use crate::bsdf::Material;
use crate::camera::{Camera, GBuffer};
use crate::error::Result;
use crate::geometry::Scene;
use crate::lights::envmap::EnvMap;
use crate::parallel::with_threads;
use crate::visibility::cache::VisibilityCache;

/// A first hit kept for previews.
#[derive(Clone, Copy, Debug)]
struct PreviewPoint {
    position: Vec3,
    /// Unit normal facing the camera.
    normal: Vec3,
    /// Unit direction to the eye.
    wo: Vec3,
    /// Pixel footprint (world units); a render looks up within the cache's
    /// `d_max_scale` times it.
    footprint: f32,
    material: Material,
    /// Radiance the surface emits towards the eye (area lights).
    emitted: Vec3,
}

/// The first hits of a view, kept to preview `J` under any lighting (module docs).
#[derive(Clone, Debug)]
pub struct LightingPreview {
    width: u32,
    height: u32,
    /// Per pixel: the hit, or the primary ray's direction where it escaped.
    points: Vec<std::result::Result<PreviewPoint, Vec3>>,
    /// [`Scene::geometry_fingerprint`] of the scene the points were traced in: caches
    /// of other scenes are refused.
    scene: u64,
}

impl LightingPreview {
    /// Traces one primary ray through each pixel centre of `camera` (the G-buffer's points,
    /// where a cache built for the camera has its records).
    pub fn new(scene: &Scene, camera: &Camera, threads: Option<usize>) -> Result<Self> {
        let g = GBuffer::render(scene, camera, 0, false, threads)?;
        Self::from_gbuffer(scene, &g)
    }

    /// The preview of `gbuffer`'s hits (which must describe `scene` as posed now): with the
    /// buffer a cache was built from, exactly the points its records were placed for.
    pub fn from_gbuffer(scene: &Scene, g: &GBuffer) -> Result<Self> {
        g.check(scene, None)?;
        let objects = &scene.mesh().objects;
        let points = (0..g.object.len())
            .map(|i| {
                let dir = Vec3::from(g.direction[i]);
                if g.object[i] < 0 {
                    return Err(dir);
                }
                let obj = g.object[i] as u32;
                let normal = Vec3::from(g.normal[i]);
                let emitted = match scene.emitter(obj) {
                    Some(light) => {
                        let first = objects[obj as usize].first_triangle;
                        let y = Vec3::from(g.position[i]);
                        light.emitted((g.prim[i] as u32 - first) as usize, y, -dir)
                    }
                    None => Vec3::ZERO,
                };
                Ok(PreviewPoint {
                    position: Vec3::from(g.position[i]),
                    normal,
                    wo: -dir,
                    footprint: g.footprint[i],
                    material: objects[obj as usize].material,
                    emitted,
                })
            })
            .collect();
        Ok(Self {
            width: g.width(),
            height: g.height(),
            points,
            scene: scene.geometry_fingerprint(),
        })
    }

    /// Image width and height.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// `J` per pixel (row-major RGB) under `env` with `cache`'s records, product cells of
    /// `product_level`. Escaped pixels show the map, emitters their emission,
    /// pixels without records black. Traces no rays.
    pub fn render(
        &self,
        cache: &VisibilityCache,
        env: &EnvMap,
        product_level: ProductLevel,
        threads: Option<usize>,
    ) -> Result<Vec<[f32; 3]>> {
        product_level.validate()?;
        cache.bind_fingerprint(self.scene)?;
        let env = &*env.at_least(2)?;
        let chroma = MapChroma::new(env);
        let state = cache.read();
        let params = cache.params();
        with_threads(threads, || {
            self.points
                .par_iter()
                .with_min_len(64)
                .map(|point| {
                    let p = match point {
                        Err(dir) => return env.eval(*dir).to_array(),
                        Ok(p) => p,
                    };
                    let lookup = state.lookup_records(
                        params,
                        p.position,
                        p.normal,
                        params.d_max_scale * p.footprint,
                    );
                    let level = product_level.for_material(&p.material);
                    let product = ProductDistribution::new(env, &p.material, p.normal, p.wo, level);
                    let j = match &product {
                        Some(product) if !lookup.neighbours().is_empty() => {
                            let tables = ControlTables::new(product, &chroma, state.store().m());
                            Interpolant::new(&state, &lookup, Some((&tables, product, env))).j
                        }
                        _ => [0.0; 3],
                    };
                    let ratios = p.material.channel_ratios();
                    std::array::from_fn(|c| p.emitted[c] + (ratios[c] as f64 * j[c]) as f32)
                })
                .collect()
        })
    }
}
