//! Area lights: one-sided emitters of constant radiance made of triangles (a quad is two).
//! They are what the decoupled-visibility (SBF) and proxy (BLD) estimators integrate over.
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

/// A one-sided emitter over triangles with constant radiance. It emits on the side its
/// triangles' winding normal `(v1 - v0) x (v2 - v0)` points to.
///
/// Invariants: at least one triangle of positive area; radiance finite and `>= 0`;
/// `cumulative_area` is non-decreasing and ends at `area`.
#[derive(Clone, Debug, PartialEq)]
pub struct AreaLight {
    /// Object id of the light's triangles in the scene that owns it.
    pub object: u32,
    radiance: Vec3,
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
            triangles,
            normals,
            cumulative_area,
            area,
        })
    }

    /// Emitted radiance, in W/(m² sr).
    pub fn radiance(&self) -> Vec3 {
        self.radiance
    }

    /// Total area, in m².
    pub fn area(&self) -> f64 {
        self.area
    }

    /// Emitted power `π · A · L` per channel, in W.
    pub fn power(&self) -> [f64; 3] {
        (self.radiance.as_dvec3() * std::f64::consts::PI * self.area).to_array()
    }

    /// The light's triangles.
    pub fn triangles(&self) -> &[[Vec3; 3]] {
        &self.triangles
    }

    /// Radiance leaving triangle `index` of the light towards `towards_viewer` (unit,
    /// pointing away from the light): the light's radiance on its front side, 0 behind.
    pub fn emitted(&self, index: usize, towards_viewer: Vec3) -> Vec3 {
        if self.normals[index].dot(towards_viewer) > 0.0 {
            self.radiance
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
            radiance: self.radiance,
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
    use crate::geometry::watertight::WatertightRay;
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
        assert_eq!(light.emitted(0, -Vec3::Y), Vec3::ONE);
        assert_eq!(light.emitted(0, Vec3::Y), Vec3::ZERO);
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
}
