//! Area lights: one-sided emitters made of triangles (a quad is two), of constant radiance
//! or, for a quad, radiance times an RGB texture over its `uv` square ([`EmissionTexture`],
//! SBF's patterned light). They are what the decoupled-visibility (SBF) and proxy (BLD)
//! estimators integrate over.
//!
//! Sampling picks a triangle in proportion to its area and a point uniformly on it (the
//! square-root warp of Shirley 1990, as pbrt-v4's `SampleUniformTriangle` does), so the
//! area density is `1 / A`. For the renderer the density is converted to solid angle at
//! the shading point `p`: `pdf(ω) = |p - y|² / (A · cos θ_y)` (pbrt-v4 §12.2), where `θ_y`
//! is the angle between the light's normal and `-ω`. Points on or behind the light's plane
//! see no emission and get no sample.

use glam::{Vec2, Vec3};

use crate::error::{Error, Result};
use crate::math::triangle_cross;

/// A sample of an area light from a shading point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightSample {
    /// Point on the light.
    pub point: Vec3,
    /// Unit direction from the shading point to `point`.
    pub direction: Vec3,
    /// Distance from the shading point to `point`.
    pub distance: f32,
    /// Solid-angle density of `direction` at the shading point, in 1/sr.
    pub pdf: f64,
    /// Radiance arriving along `direction` (before visibility), in W/(m² sr).
    pub radiance: Vec3,
}

/// Largest side of an [`EmissionTexture`], in texels.
pub const MAX_TEXTURE_SIDE: usize = 4096;

/// An RGB pattern over a quad light's `uv` square, read at the nearest texel: texel
/// `(x, y)` covers `u ∈ [x, x+1)/width`, `v ∈ [y, y+1)/height`. The quad `v0 v1 v2 v3` has
/// `uv = (0, 0)` at `v0`, `(1, 0)` at `v1` and `(0, 1)` at `v3` (exact for parallelograms;
/// other planar quads are read through the same affine map).
///
/// Invariants: `texels.len() == width · height > 0`; every value finite, `>= 0`.
#[derive(Clone, Debug, PartialEq)]
pub struct EmissionTexture {
    width: usize,
    height: usize,
    texels: Vec<[f32; 3]>,
}

impl EmissionTexture {
    /// A texture of `width x height` texels, row-major (`texels[y * width + x]`); values
    /// must be finite and `>= 0` (an error naming `texture` otherwise).
    pub fn new(width: usize, height: usize, texels: Vec<[f32; 3]>) -> Result<Self> {
        if width == 0 || height == 0 || width > MAX_TEXTURE_SIDE || height > MAX_TEXTURE_SIDE {
            return Err(Error::invalid(
                "texture",
                format!("sides must lie in [1, {MAX_TEXTURE_SIDE}], got {height} x {width}"),
            ));
        }
        if texels.len() != width * height {
            return Err(Error::invalid(
                "texture",
                format!("expected {} texels, got {}", width * height, texels.len()),
            ));
        }
        if let Some(bad) = texels.iter().find(|t| !super::valid_radiance(**t)) {
            return Err(Error::invalid("texture", super::radiance_problem(*bad)));
        }
        Ok(Self {
            width,
            height,
            texels,
        })
    }

    /// The texel containing `(u, v)` (clamped to the square).
    fn at(&self, u: f32, v: f32) -> Vec3 {
        let x = ((u * self.width as f32) as isize).clamp(0, self.width as isize - 1) as usize;
        let y = ((v * self.height as f32) as isize).clamp(0, self.height as isize - 1) as usize;
        Vec3::from_array(self.texels[y * self.width + x])
    }

    /// Mean of the texels per channel (the texture's average over the square).
    fn mean(&self) -> [f64; 3] {
        let mut sum = [0.0f64; 3];
        for t in &self.texels {
            (0..3).for_each(|c| sum[c] += t[c] as f64);
        }
        sum.map(|v| v / self.texels.len() as f64)
    }
}

/// The affine `uv` map of a quad light: `y = origin + u·edge_u + v·edge_v`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct UvFrame {
    origin: Vec3,
    /// Dual vectors: `u = (y − origin)·dual_u`, `v = (y − origin)·dual_v` in the plane.
    dual_u: Vec3,
    dual_v: Vec3,
}

impl UvFrame {
    /// The frame of a quad split by [`quad_triangles`]; `None` for any other triangles.
    fn of_quad(triangles: &[[Vec3; 3]]) -> Option<Self> {
        let [t0, t1] = triangles else {
            return None;
        };
        if t1[0] != t0[0] || t1[1] != t0[2] {
            return None;
        }
        let (origin, eu, ev) = (t0[0], t0[1] - t0[0], t1[2] - t0[0]);
        let (a, b, c) = (eu.dot(eu), eu.dot(ev), ev.dot(ev));
        let det = a * c - b * b;
        if !(det.abs() > f32::MIN_POSITIVE && det.is_finite()) {
            return None;
        }
        Some(Self {
            origin,
            dual_u: (eu * c - ev * b) / det,
            dual_v: (ev * a - eu * b) / det,
        })
    }

    fn uv(&self, y: Vec3) -> (f32, f32) {
        let d = y - self.origin;
        (d.dot(self.dual_u), d.dot(self.dual_v))
    }
}

/// A one-sided emitter over triangles. It emits on the side its triangles' winding normal
/// `(v1 - v0) x (v2 - v0)` points to: its radiance, times its texture where it has one.
///
/// Invariants: at least one triangle of positive area; radiance finite and `>= 0`;
/// `cumulative_area` is non-decreasing and ends at `area`; a texture only with the `uv`
/// frame of a quad.
#[derive(Clone, Debug, PartialEq)]
pub struct AreaLight {
    /// Object id of the light's triangles in the scene that owns it.
    pub object: u32,
    radiance: Vec3,
    texture: Option<(EmissionTexture, UvFrame)>,
    triangles: Vec<[Vec3; 3]>,
    normals: Vec<Vec3>,
    cumulative_area: Vec<f64>,
    area: f64,
}

impl AreaLight {
    /// An emitter over `triangles` of object `object`. Degenerate triangles are kept (so
    /// indices match the object's) but never sampled; a light of zero total area, or a
    /// negative, NaN or infinite radiance, is an error.
    pub fn new(object: u32, triangles: Vec<[Vec3; 3]>, radiance: [f32; 3]) -> Result<Self> {
        if !super::valid_radiance(radiance) {
            return Err(Error::invalid(
                "radiance",
                super::radiance_problem(radiance),
            ));
        }
        let mut cumulative_area = Vec::with_capacity(triangles.len());
        let mut normals = Vec::with_capacity(triangles.len());
        let mut area = 0.0f64;
        for t in &triangles {
            let cross = triangle_cross(t);
            area += 0.5 * cross.as_dvec3().length();
            cumulative_area.push(area);
            normals.push(cross.normalize_or_zero());
        }
        if !(area > 0.0 && area.is_finite()) {
            return Err(Error::invalid(
                "vertices",
                format!("an area light needs a positive, finite area, got {area}"),
            ));
        }
        Ok(Self {
            object,
            radiance: Vec3::from_array(radiance),
            texture: None,
            triangles,
            normals,
            cumulative_area,
            area,
        })
    }

    /// Emitted radiance, in W/(m² sr): the scale of the texture where there is one.
    pub fn radiance(&self) -> Vec3 {
        self.radiance
    }

    /// The texture, if any.
    pub fn texture(&self) -> Option<&EmissionTexture> {
        self.texture.as_ref().map(|t| &t.0)
    }

    /// The same light with `texture` (or none). Only a quad light (two triangles from
    /// [`quad_triangles`]) takes one; otherwise an error naming `texture`.
    pub fn with_texture(mut self, texture: Option<EmissionTexture>) -> Result<Self> {
        self.texture = match texture {
            None => None,
            Some(t) => {
                let frame = UvFrame::of_quad(&self.triangles).ok_or_else(|| {
                    Error::invalid("texture", "only a quad light (4 vertices) takes a texture")
                })?;
                Some((t, frame))
            }
        };
        Ok(self)
    }

    /// The same light (texture kept) with another `radiance`.
    pub fn with_radiance(&self, radiance: [f32; 3]) -> Result<Self> {
        let light = Self::new(self.object, self.triangles.clone(), radiance)?;
        light.with_texture(self.texture().cloned())
    }

    /// The same light (radiance and texture kept) over `triangles` (the object moved).
    pub fn moved(&self, triangles: Vec<[Vec3; 3]>) -> Result<Self> {
        let light = Self::new(self.object, triangles, self.radiance.to_array())?;
        light.with_texture(self.texture().cloned())
    }

    /// Radiance leaving point `y` of the light's front side.
    pub fn radiance_at(&self, y: Vec3) -> Vec3 {
        match &self.texture {
            None => self.radiance,
            Some((texture, frame)) => {
                let (u, v) = frame.uv(y);
                self.radiance * texture.at(u, v)
            }
        }
    }

    /// Total area, in m².
    pub fn area(&self) -> f64 {
        self.area
    }

    /// Emitted power `π · A · L` per channel, in W (`L` the texture's mean times the
    /// radiance for a textured light).
    pub fn power(&self) -> [f64; 3] {
        let mean = self.texture().map_or([1.0; 3], |t| t.mean());
        let base = self.radiance.as_dvec3() * std::f64::consts::PI * self.area;
        std::array::from_fn(|c| base[c] * mean[c])
    }

    /// The light's triangles.
    pub fn triangles(&self) -> &[[Vec3; 3]] {
        &self.triangles
    }

    /// Radiance leaving point `y` of triangle `index` of the light towards
    /// `towards_viewer` (unit, pointing away from the light): [`Self::radiance_at`] on its
    /// front side, 0 behind.
    pub fn emitted(&self, index: usize, y: Vec3, towards_viewer: Vec3) -> Vec3 {
        if self.normals[index].dot(towards_viewer) > 0.0 {
            self.radiance_at(y)
        } else {
            Vec3::ZERO
        }
    }

    /// Samples a point on the light as seen from `p`, from `uc` (picks the triangle) and
    /// `u` (the point on it), all in `[0,1)`. `None` when the sampled point faces away from
    /// `p` or coincides with it (including every `p` on the light's plane).
    pub fn sample(&self, p: Vec3, uc: f32, u: Vec2) -> Option<LightSample> {
        let target = uc as f64 * self.area;
        let index = self
            .cumulative_area
            .partition_point(|&c| c <= target)
            .min(self.triangles.len() - 1);
        let [a, b, c] = self.triangles[index];
        let su = u.x.sqrt();
        let (b0, b1) = (1.0 - su, u.y * su);
        let point = a * b0 + b * b1 + c * (1.0 - b0 - b1);
        let to_light = point - p;
        let distance = to_light.length();
        if distance.is_nan() || distance <= 0.0 {
            return None;
        }
        let direction = to_light / distance;
        let pdf = self.pdf_at(p, point, self.normals[index]);
        if !(pdf > 0.0 && pdf.is_finite()) {
            return None;
        }
        Some(LightSample {
            point,
            direction,
            distance,
            pdf,
            radiance: self.radiance_at(point),
        })
    }

    /// Solid-angle density at `p` of sampling point `y` of the light, whose unit normal
    /// there is `normal`: `|p - y|² / (A · cos θ_y)`; 0 when `y` faces away from `p`.
    pub fn pdf_at(&self, p: Vec3, y: Vec3, normal: Vec3) -> f64 {
        let d = (p - y).as_dvec3();
        let dist2 = d.length_squared();
        if dist2 == 0.0 {
            return 0.0;
        }
        let cos = normal.as_dvec3().dot(d) / dist2.sqrt();
        if cos > 0.0 {
            dist2 / (self.area * cos)
        } else {
            0.0
        }
    }

    /// Normal of triangle `index` (unit; zero for a degenerate triangle).
    pub fn normal(&self, index: usize) -> Vec3 {
        self.normals[index]
    }
}

/// Triangles of a quad `v0 v1 v2 v3` (given in order around its border), split along the
/// `v0`-`v2` diagonal. Both keep the winding of the quad.
pub fn quad_triangles(v: [Vec3; 4]) -> [[Vec3; 3]; 2] {
    [[v[0], v[1], v[2]], [v[0], v[2], v[3]]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::bvh::watertight::WatertightRay;
    use crate::sampling::chi2::{chi2_sphere, Chi2Params};
    use crate::sampling::rng::SampleRng;

    /// A 1 x 0.5 quad at height 2 facing down, tilted a little.
    fn ceiling_quad() -> AreaLight {
        let v = [
            Vec3::new(-0.5, 2.0, -0.25),
            Vec3::new(0.5, 2.1, -0.25),
            Vec3::new(0.5, 2.1, 0.25),
            Vec3::new(-0.5, 2.0, 0.25),
        ];
        AreaLight::new(0, quad_triangles(v).to_vec(), [1.0, 2.0, 3.0]).unwrap()
    }

    /// Solid-angle pdf of direction `d` from `p` by brute force over the light's triangles.
    fn pdf_along(light: &AreaLight, p: Vec3, d: Vec3) -> f64 {
        let ray = WatertightRay::new(p.into(), d.into());
        light
            .triangles()
            .iter()
            .enumerate()
            .filter_map(|(i, t)| {
                let tri = [t[0].into(), t[1].into(), t[2].into()];
                ray.intersect(&tri, f32::INFINITY)
                    .map(|h| light.pdf_at(p, p + d * h.t, light.normal(i)))
            })
            .sum()
    }

    fn uniforms(i: u64) -> (f32, Vec2) {
        let r = SampleRng::new(5, i, 0);
        (r.get(0), Vec2::new(r.get(1), r.get(2)))
    }

    #[test]
    fn light_sampling_matches_its_pdf() {
        // The quad's winding makes it face down, towards the points below it.
        let light = ceiling_quad();
        assert!(light.normal(0).y < -0.9);
        for p in [
            Vec3::ZERO,
            Vec3::new(3.0, 1.5, 0.2),
            Vec3::new(0.1, 1.9, 0.0),
        ] {
            let samples = (0..200_000).map(|i| {
                let (uc, u) = uniforms(i);
                light.sample(p, uc, u).map(|s| s.direction)
            });
            let outcome = chi2_sphere(
                samples,
                |d| pdf_along(&light, p, d),
                // The light's outline cuts bins; a fine sub-grid integrates the slivers.
                &Chi2Params::with_resolution(32).with_subdivisions(32),
            );
            assert!(outcome.passed, "{p}: {outcome:?}");
            assert_eq!(outcome.rejected, 0);
        }
    }

    #[test]
    fn points_behind_or_on_the_plane_get_no_sample() {
        let v = [
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(0.0, 1.0, 1.0),
        ];
        // Winding (x, then z) gives a normal of -y: it lights what is below.
        let light = AreaLight::new(0, quad_triangles(v).to_vec(), [1.0; 3]).unwrap();
        assert!(light.normal(0).y < -0.99);
        for i in 0..1000 {
            let (uc, u) = uniforms(i);
            assert!(
                light.sample(Vec3::new(0.5, 2.0, 0.5), uc, u).is_none(),
                "behind"
            );
            assert!(
                light.sample(Vec3::new(3.0, 1.0, 0.5), uc, u).is_none(),
                "on the plane"
            );
            let s = light.sample(Vec3::new(0.5, 0.0, 0.5), uc, u).unwrap();
            assert!(s.pdf.is_finite() && s.pdf > 0.0 && s.distance > 0.0);
        }
        // Emission is one-sided.
        assert_eq!(light.emitted(0, Vec3::ZERO, -Vec3::Y), Vec3::ONE);
        assert_eq!(light.emitted(0, Vec3::ZERO, Vec3::Y), Vec3::ZERO);
    }

    #[test]
    fn irradiance_from_a_small_light_matches_the_point_light_limit() {
        // A tiny square at distance 10 straight above: E ≈ L · A / d².
        let s = 0.01f32;
        let v = [
            Vec3::new(0.0, 10.0, 0.0),
            Vec3::new(s, 10.0, 0.0),
            Vec3::new(s, 10.0, s),
            Vec3::new(0.0, 10.0, s),
        ];
        let light = AreaLight::new(0, quad_triangles(v).to_vec(), [2.0; 3]).unwrap();
        let n = 10_000;
        let e: f64 = (0..n)
            .map(|i| {
                let (uc, u) = uniforms(i);
                let smp = light.sample(Vec3::ZERO, uc, u).unwrap();
                smp.radiance.x as f64 * smp.direction.y as f64 / smp.pdf
            })
            .sum::<f64>()
            / n as f64;
        let expected = 2.0 * (s as f64).powi(2) / 100.0;
        assert!((e - expected).abs() < 1e-4 * expected, "{e} vs {expected}");
        assert!((light.power()[0] - std::f64::consts::PI * 2.0 * 1e-4).abs() < 1e-9);
    }

    #[test]
    fn bad_lights_are_rejected() {
        let degenerate = vec![[Vec3::ZERO, Vec3::X, Vec3::X * 2.0]];
        let e = AreaLight::new(0, degenerate, [1.0; 3])
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("vertices:"), "{e}");
        let tri = vec![[Vec3::ZERO, Vec3::X, Vec3::Z]];
        for bad in [
            [-1.0, 0.0, 0.0],
            [f32::NAN, 0.0, 0.0],
            [f32::INFINITY, 0.0, 0.0],
        ] {
            let e = AreaLight::new(0, tri.clone(), bad).unwrap_err().to_string();
            assert!(e.starts_with("radiance:"), "{e}");
        }
        // A degenerate triangle next to a good one is never sampled.
        let mixed = vec![
            [Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
            [Vec3::ZERO, Vec3::Z, Vec3::X],
        ];
        let light = AreaLight::new(0, mixed, [1.0; 3]).unwrap();
        for i in 0..1000 {
            let (uc, u) = uniforms(i);
            let s = light.sample(Vec3::new(0.2, 1.0, 0.2), uc, u).unwrap();
            assert!(s.point.x + s.point.z <= 1.0 + 1e-6 && s.point.y == 0.0);
        }
    }

    #[test]
    fn textured_quads_emit_their_texels_and_integrate_to_the_quadrature() {
        // A 2 x 1 m quad facing down (-y) at height 1, red on its first half, green on the
        // second; uv (0, 0) at v0, (1, 0) at v1, (0, 1) at v3.
        let v = [
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
            Vec3::new(2.0, 1.0, 1.0),
            Vec3::new(0.0, 1.0, 1.0),
        ];
        let texture = EmissionTexture::new(2, 1, vec![[4.0, 0.0, 0.0], [0.0, 2.0, 0.0]]).unwrap();
        let light = AreaLight::new(0, quad_triangles(v).to_vec(), [1.0, 1.0, 0.5])
            .unwrap()
            .with_texture(Some(texture.clone()))
            .unwrap();
        assert_eq!(
            light.radiance_at(Vec3::new(0.5, 1.0, 0.5)),
            Vec3::new(4.0, 0.0, 0.0)
        );
        assert_eq!(
            light.radiance_at(Vec3::new(1.5, 1.0, 0.9)),
            Vec3::new(0.0, 2.0, 0.0)
        );
        assert_eq!(
            light.emitted(1, Vec3::new(1.5, 1.0, 0.9), -Vec3::Y),
            Vec3::new(0.0, 2.0, 0.0)
        );
        let pi = std::f64::consts::PI;
        let power = light.power();
        assert!((power[0] - pi * 2.0 * 2.0).abs() < 1e-9 && (power[1] - pi * 2.0).abs() < 1e-9);
        assert_eq!(power[2], 0.0);
        // ∫ L cos dω at a point below the red half, by light samples, against a 400 x 200
        // midpoint quadrature over the quad: within 4 standard errors.
        let p = Vec3::new(0.4, 0.0, 0.5);
        let quadrature = {
            let mut sum = Vec3::ZERO.as_dvec3();
            let (nx, nz) = (400, 200);
            for i in 0..nx {
                for k in 0..nz {
                    let y = Vec3::new(
                        (i as f32 + 0.5) * 2.0 / nx as f32,
                        1.0,
                        (k as f32 + 0.5) / nz as f32,
                    );
                    let d = y - p;
                    let r2 = d.length_squared() as f64;
                    let cos = (d.y as f64) / r2.sqrt();
                    sum +=
                        light.radiance_at(y).as_dvec3() * cos * cos / r2 * (2.0 / (nx * nz) as f64);
                }
            }
            sum
        };
        let (mut mean, mut m2) = ([0.0f64; 3], [0.0f64; 3]);
        let n = 200_000;
        for i in 0..n {
            let (uc, u) = uniforms(i);
            let x = light.sample(p, uc, u).map_or(Vec3::ZERO.as_dvec3(), |s| {
                s.radiance.as_dvec3() * s.direction.y as f64 / s.pdf
            });
            for c in 0..3 {
                let delta = x[c] - mean[c];
                mean[c] += delta / (i + 1) as f64;
                m2[c] += delta * (x[c] - mean[c]);
            }
        }
        for c in 0..2 {
            let se = (m2[c] / (n - 1) as f64 / n as f64).sqrt();
            assert!(
                (mean[c] - quadrature[c]).abs() < 4.0 * se + 1e-4 * quadrature[c],
                "{c}: {} vs {}",
                mean[c],
                quadrature[c]
            );
        }
        // The texture follows a move and a new radiance; triangles take none.
        let moved = light
            .moved(
                light
                    .triangles()
                    .iter()
                    .map(|t| t.map(|x| x + Vec3::X))
                    .collect(),
            )
            .unwrap();
        assert_eq!(
            moved.radiance_at(Vec3::new(1.5, 1.0, 0.5)),
            Vec3::new(4.0, 0.0, 0.0)
        );
        let brighter = light.with_radiance([2.0; 3]).unwrap();
        assert_eq!(
            brighter.radiance_at(Vec3::new(1.5, 1.0, 0.5)),
            Vec3::new(0.0, 4.0, 0.0)
        );
        let tri = AreaLight::new(0, vec![[v[0], v[1], v[2]]], [1.0; 3]).unwrap();
        let e = tri.with_texture(Some(texture)).unwrap_err().to_string();
        assert!(e.starts_with("texture"), "{e}");
        for bad in [vec![[-1.0, 0.0, 0.0]], vec![[f32::NAN, 0.0, 0.0]]] {
            assert!(EmissionTexture::new(1, 1, bad).is_err());
        }
        assert!(EmissionTexture::new(2, 2, vec![[1.0; 3]]).is_err());
    }
}
