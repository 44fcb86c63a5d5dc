//! `hairball`: a dense tangle of thin tubes above a plane.
//!
//! **Purpose.** Millions of small triangles in a small volume, after the classic hairball
//! test scene: a stress test for BVH build and traversal, and a case where visibility
//! changes on a scale far below the record spacing (near the ball's surface points see
//! part of the sky through gaps; inside, almost nothing).
//!
//! **World** (metres):
//! - `ground`: a 300 x 300 m square centred at the origin at y = 0 (it reaches the
//!   horizon), normal +y; cells of at most 1 m / sqrt(detail) over the central 6 x 6 m,
//!   growing 1.5 times per step outside it.
//! - `hair`: 1,240 x detail random smooth curves inside the ball of radius 1 centred at
//!   (0, 1.1, 0), each a closed tube of 6 sides and 100 segments of 1.5 cm (1.5 m long),
//!   radius 5-10 mm, with flat end caps. A curve is a random walk whose turning rate
//!   itself wanders slowly (smooth, with a radius of curvature of a few tens of cm); it is
//!   steered back inward near the ball's surface and reflected at it, so tube centres stay
//!   within the ball (surfaces within 1 cm of it).
//!
//! **Triangles.** 1,208 per curve (1,200 for the sides, 8 for the caps) plus 1,352 for
//! the ground: 1,499,272 at detail 1.
//!
//! **Camera.** Eye (1.9, 1.6, 2.9) looking at (0, 0.95, 0), vertical field of view 40
//! degrees, 256 x 192: the ball fills about 80% of the frame's height, with the plane
//! below and behind it and the sky above the horizon. Curves depend on the seed; they
//! are generated in parallel (one work item per curve) into fixed slots, so the result
//! does not depend on the thread count.
//!
//! **Environment.** [`super::daylight`] with the sun high, at azimuth 200°, elevation 60°
//! (behind and above the camera's left shoulder): the tangle shadows itself and the plane
//! under it.

use glam::Vec3;
use rayon::prelude::*;

use super::shapes::{graded, ground_lattice, sphere_dir, tube, tube_triangles, uniform, Tri};
use super::{camera, check_detail, setup, Setup};
use crate::bsdf::Material;
use crate::error::Result;
use crate::geometry::Mesh;
use crate::lights::EnvMap;
use crate::sampling::rng::mix64;

/// Centre of the ball of hair (m).
pub const CENTER: Vec3 = Vec3::new(0.0, 1.1, 0.0);
/// Radius of the ball (m).
pub const RADIUS: f32 = 1.0;
/// Curves at detail 1.
pub const CURVES: f32 = 1240.0;
/// Segments per curve.
pub const SEGMENTS: usize = 100;
/// Sides of each tube.
pub const SIDES: usize = 6;
/// Triangles per curve.
pub const CURVE_TRIANGLES: usize = tube_triangles(SEGMENTS + 1, SIDES, true);

const STEP: f32 = 0.015;
const SALT: u64 = 0x6861_6972;

/// The centre line of curve `c` (`SEGMENTS + 1` points) and its tube radius.
fn curve(seed: u64, c: u64, points: &mut Vec<Vec3>) -> f32 {
    let u = |k: u64, d: u64| uniform(seed, c, k, d);
    points.clear();
    let mut p = CENTER + sphere_dir(u(0, 0), u(0, 1)) * (0.9 * RADIUS * u(0, 2).cbrt());
    let mut d = sphere_dir(u(0, 3), u(0, 4));
    let radius = 0.005 + 0.005 * u(0, 5);
    let mut w = Vec3::ZERO;
    points.push(p);
    for k in 1..=SEGMENTS as u64 {
        // The turn per step w is an AR(1) process, so the curvature varies smoothly.
        let r = Vec3::new(u(k, 0), u(k, 1), u(k, 2)) * 2.0 - Vec3::ONE;
        w = w * 0.92 + r * 0.04;
        d = (d + w).normalize_or(d);
        let q = p - CENTER;
        let dist = q.length();
        if dist > 0.8 * RADIUS {
            let push = (dist / RADIUS - 0.8) / 0.2 * 0.5;
            d = (d - q / dist * push).normalize_or(d);
        }
        let mut next = p + d * STEP;
        let out = next - CENTER;
        if out.length() > RADIUS {
            let n = out.normalize();
            d -= n * (2.0 * d.dot(n)).max(0.0);
            w -= n * (2.0 * w.dot(n)).max(0.0);
            next = p + d * STEP;
            if (next - CENTER).length() > RADIUS {
                next = CENTER + (next - CENTER).normalize() * RADIUS;
            }
        }
        p = next;
        points.push(p);
    }
    radius
}

/// Builds the setup (see the module docs).
pub fn build(detail: f32, seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    let mut mesh = Mesh::new();

    let mut t = Vec::new();
    let xs = graded(3.0, 1.0 / detail.sqrt(), 150.0, 1.5);
    ground_lattice(&mut t, &xs, &xs, 0.0);
    mesh.add_triangles(
        t,
        Material::lambert([0.5, 0.5, 0.5])?,
        Some("ground".into()),
    )?;

    let n = ((CURVES * detail).round() as usize).max(1);
    let seed = mix64(seed ^ SALT);
    let mut hair = vec![[Vec3::ZERO; 3]; n * CURVE_TRIANGLES];
    hair.par_chunks_mut(CURVE_TRIANGLES)
        .enumerate()
        .for_each_init(
            || {
                (
                    Vec::with_capacity(SEGMENTS + 1),
                    Vec::<Tri>::with_capacity(CURVE_TRIANGLES),
                )
            },
            |(points, buf), (c, dst)| {
                let radius = curve(seed, c as u64, points);
                buf.clear();
                tube(buf, points, radius, SIDES, true);
                dst.copy_from_slice(buf);
            },
        );
    mesh.add_triangles(
        hair,
        Material::phong([0.45, 0.3, 0.18], [0.2; 3], 30.0)?,
        Some("hair".into()),
    )?;

    let cam = camera([1.9, 1.6, 2.9], [0.0, 0.95, 0.0], 40.0)?;
    Ok(setup("hairball", mesh, cam, envmap()?))
}

/// The default environment: sky and a high sun (see the module docs).
pub fn envmap() -> Result<EnvMap> {
    super::daylight(200.0, 60.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::testing::*;

    #[test]
    fn loads_with_documented_size() {
        let d = 0.05;
        let s = build(d, 0).unwrap();
        let cells = graded(3.0, 1.0 / d.sqrt(), 150.0, 1.5).len() - 1;
        let expect = 62 * CURVE_TRIANGLES + 2 * cells * cells;
        check_basic(&s, "hairball", expect..=expect);
        assert_eq!(centre_object(&s), "hair");
        check_seeds(build, d, true);
        check_scaling(build, d);
    }

    #[test]
    fn curves_are_smooth_and_inside_the_ball() {
        let mut pts = Vec::new();
        for c in 0..200 {
            let r = curve(7, c, &mut pts);
            assert!((0.005..=0.01).contains(&r));
            assert_eq!(pts.len(), SEGMENTS + 1);
            for w in pts.windows(3) {
                assert!(((w[1] - w[0]).length() - STEP).abs() < 5e-4);
                let turn = (w[1] - w[0]).normalize().dot((w[2] - w[1]).normalize());
                // Free curves turn gently; steering near the surface turns harder, and
                // reflections at the surface are the only sharp turns.
                let r = (w[1] - CENTER).length();
                if r < 0.8 * RADIUS {
                    assert!(turn > 0.97, "turn {turn} at {r}");
                } else if r < RADIUS - 1.5 * STEP {
                    assert!(turn > 0.8, "turn {turn} at {r}");
                }
            }
            assert!(pts.iter().all(|p| (*p - CENTER).length() <= RADIUS + 1e-4));
        }
    }

    #[test]
    fn the_camera_sees_ball_and_plane() {
        let s = build(0.05, 0).unwrap();
        let c = &s.camera;
        let mut counters = crate::geometry::TraversalCounters::default();
        let mut hit_name = |x: f32, y: f32| {
            let d = c.direction(x, y);
            let h = s.scene.intersect1(c.eye, d, f32::INFINITY, &mut counters);
            h.map(|h| s.scene.mesh().objects[h.obj as usize].name.clone())
        };
        assert_eq!(hit_name(128.0, 185.0).as_deref(), Some("ground"));
        assert_eq!(hit_name(5.0, 180.0).as_deref(), Some("ground"));
    }
}
