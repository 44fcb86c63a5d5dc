//! Records that see area lights: where a record's ray stops when emitters count as visible
//! ([`super::RecordTracing::emitters_visible`]).
//!
//! A record's bit stands for every direction of its texel, but is traced along one of them.
//! For the sky that is CAM08's approximation; for an area light a few texels wide it is
//! not enough: a texel at the light's rim is traced along a ray that may pass beside the
//! light and hit the ceiling the light hangs from, and the bit would say "blocked" for the
//! part of the texel that does reach the light. So the ray stops where it crosses the
//! plane of an emitter triangle within the triangle grown by the texel's angular radius at
//! that distance: the bit then says whether the way to the light's plane, next to the
//! light, is clear. A ray that reaches no emitter is traced unbounded as before.

use glam::Vec3;

use crate::lights::AreaLight;

/// Cosine between a ray and an emitter's normal below which the grown triangle stops
/// growing with the grazing angle (about 87°).
const MIN_COSINE: f32 = 0.05;

/// Angular radius (radians) of the cone that holds a texel of a `2^m x 2^m` equal-area
/// map: a texel spans `4π / 4^m` steradians, the cone of that solid angle has half-angle
/// about `sqrt(Ω / π)`, and the texel's corners reach `√2` times further.
pub(super) fn texel_radius(m: u32) -> f32 {
    let solid_angle = 4.0 * std::f32::consts::PI / (1u64 << (2 * m)) as f32;
    (solid_angle / std::f32::consts::PI).sqrt() * std::f32::consts::SQRT_2
}

/// One emitter triangle with what [`EmitterPlanes::distance`] tests per ray.
struct EmitterTriangle {
    /// A vertex, and the (unnormalised) normal the crossing's distance is taken with.
    a: Vec3,
    normal: Vec3,
    unit: Vec3,
    /// Per edge, a point on it and its in-plane normal pointing into the triangle.
    edges: [(Vec3, Vec3); 3],
}

/// The emitter triangles of a scene's area lights (degenerate ones left out), prepared once
/// for the rays of a record.
pub(super) struct EmitterPlanes(Vec<EmitterTriangle>);

impl EmitterPlanes {
    pub(super) fn new(lights: &[AreaLight]) -> Self {
        let triangles = lights
            .iter()
            .flat_map(|light| light.triangles())
            .filter_map(|&[a, b, c]| {
                let normal = (b - a).cross(c - a);
                if normal == Vec3::ZERO {
                    return None;
                }
                let unit = normal.normalize();
                let edges =
                    [(a, b), (b, c), (c, a)].map(|(u, v)| (u, unit.cross(v - u).normalize()));
                Some(EmitterTriangle {
                    a,
                    normal,
                    unit,
                    edges,
                })
            })
            .collect();
        Self(triangles)
    }

    /// The distance along unit `dir` from `origin` at which the ray crosses the plane of an
    /// emitter triangle within angle `slack` (radians, to first order) of that triangle as
    /// seen from `origin`: inside the triangle grown in its plane by `slack · t / |cos|`
    /// (`t` the crossing's distance, `cos` between `dir` and the normal). The nearest such
    /// crossing; `inf` when there is none. Either side of a triangle counts: behind a light
    /// nothing is emitted toward the record.
    pub(super) fn distance(&self, origin: Vec3, dir: Vec3, slack: f32) -> f32 {
        let mut nearest = f32::INFINITY;
        for tri in &self.0 {
            let along = tri.normal.dot(dir);
            if along == 0.0 {
                continue;
            }
            let t = tri.normal.dot(tri.a - origin) / along;
            if !(t > 0.0 && t < nearest) {
                continue;
            }
            let p = origin + dir * t;
            // An angle `slack` off the ray spans `slack · t` across it, stretched along a
            // plane seen at a grazing angle (capped where it nears the plane's edge-on).
            let grown = slack * t / tri.unit.dot(dir).abs().max(MIN_COSINE);
            // Signed in-plane distance to each edge, positive inside.
            if tri
                .edges
                .iter()
                .all(|&(u, inward)| (p - u).dot(inward) >= -grown)
            {
                nearest = t;
            }
        }
        nearest
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lights::area::quad_triangles;

    fn ceiling_light() -> AreaLight {
        // A 1 x 1 m light at y = 2, facing down.
        let q = [
            Vec3::new(-0.5, 2.0, -0.5),
            Vec3::new(0.5, 2.0, -0.5),
            Vec3::new(0.5, 2.0, 0.5),
            Vec3::new(-0.5, 2.0, 0.5),
        ];
        AreaLight::new(0, quad_triangles(q).to_vec(), [1.0; 3]).unwrap()
    }

    #[test]
    fn rays_stop_at_the_light_and_beside_it_within_the_slack() {
        let planes = EmitterPlanes::new(&[ceiling_light()]);
        let o = Vec3::ZERO;
        // Straight up: through the light, 2 m away.
        assert!((planes.distance(o, Vec3::Y, 0.0) - 2.0).abs() < 1e-6);
        // Toward (0.6, 2, 0): 0.1 m beside the light's edge at about 2.09 m.
        let beside = Vec3::new(0.6, 2.0, 0.0).normalize();
        assert_eq!(planes.distance(o, beside, 0.0), f32::INFINITY);
        assert_eq!(planes.distance(o, beside, 0.04), f32::INFINITY);
        let t = planes.distance(o, beside, 0.06);
        assert!((t - Vec3::new(0.6, 2.0, 0.0).length()).abs() < 1e-5, "{t}");
        // Seen at a grazing angle, 0.1 m beyond the edge z = -0.5 is 0.008 rad away.
        let from = Vec3::new(0.0, 1.5, -3.0);
        let grazing = (Vec3::new(0.0, 2.0, -0.6) - from).normalize();
        assert_eq!(planes.distance(from, grazing, 0.0075), f32::INFINITY);
        assert!(planes.distance(from, grazing, 0.0095).is_finite());
        // Away from it, and parallel to its plane.
        assert_eq!(planes.distance(o, -Vec3::Y, 1.0), f32::INFINITY);
        assert_eq!(planes.distance(o, Vec3::X, 1.0), f32::INFINITY);
        assert_eq!(
            EmitterPlanes::new(&[]).distance(o, Vec3::Y, 1.0),
            f32::INFINITY
        );
    }

    #[test]
    fn a_texels_cone_covers_its_solid_angle() {
        for m in 1..=7 {
            let r = texel_radius(m);
            let cone = 2.0 * std::f32::consts::PI * (1.0 - (r / std::f32::consts::SQRT_2).cos());
            let texel = 4.0 * std::f32::consts::PI / (1u64 << (2 * m)) as f32;
            // Within 20% for the small-angle formula up to the coarsest maps.
            assert!((cone / texel - 1.0).abs() < 0.2, "m {m}: {cone} vs {texel}");
        }
    }
}
