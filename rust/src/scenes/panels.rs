//! `panels`: a few huge triangles spanning the scene beside small detail.
//!
//! **Purpose.** Four slanted panels, each two triangles tens of metres across, lean over a
//! field of small objects: the panels' boxes overlap nearly every node of a BVH that the
//! small objects would otherwise split finely, and they block 61% of ground rays.
//!
//! **World** (metres, ground at y = 0):
//! - `ground`: 80 x 80 m, two triangles (huge too).
//! - `panels`: four quads (eight triangles) 60 m long and 12 to 18 m wide, each leaning
//!   at 50° to 70° over the middle from one side of a 30 m square, leaving gaps between.
//! - `pebbles`: [`COUNT`] small objects (icospheres of level 2, 4 to 20 cm) scattered over
//!   the central 20 x 20 m.
//!
//! **Triangles.** 64,010 at detail 1 (pebbles scale with detail).
//!
//! **Camera.** Eye (3, 2.5, 12) looking at (0, 0.2, 0), vertical field of view 55 degrees.
//!
//! **Environment.** [`super::daylight`], sun at azimuth 30°, elevation 55°.
//!
//! **Randomness.** `seed` fixes the pebbles.

use glam::Vec3;

use super::shapes::{icosphere, quad, uniform};
use super::{camera, check_detail, daylight, setup, Setup};
use crate::bsdf::Material;
use crate::error::Result;
use crate::geometry::Mesh;

/// Pebbles at detail 1.
pub const COUNT: usize = 200;

/// Builds the setup (see the module docs).
pub fn build(detail: f32, seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    let mut mesh = Mesh::new();
    let mut t = Vec::new();
    quad(
        &mut t,
        Vec3::new(-40.0, 0.0, -40.0),
        Vec3::new(-40.0, 0.0, 40.0),
        Vec3::new(40.0, 0.0, 40.0),
        Vec3::new(40.0, 0.0, -40.0),
    );
    mesh.add_triangles(
        t,
        Material::lambert([0.5, 0.52, 0.48])?,
        Some("ground".into()),
    )?;

    // Each panel: a base edge on the ground along one side of the square, tilted inward.
    let mut t = Vec::new();
    let sides = [
        (Vec3::new(0.0, 0.0, -15.0), Vec3::X, 60f32, 18.0f32),
        (Vec3::new(15.0, 0.0, 0.0), Vec3::Z, 52.0, 14.0),
        (Vec3::new(0.0, 0.0, 15.0), -Vec3::X, 68.0, 16.0),
        (Vec3::new(-15.0, 0.0, 0.0), -Vec3::Z, 58.0, 12.0),
    ];
    for (mid, along, tilt_deg, width) in sides {
        let inward = -mid.normalize();
        let up = (Vec3::Y * tilt_deg.to_radians().sin() + inward * tilt_deg.to_radians().cos())
            .normalize();
        let (a, b) = (mid - along * 30.0, mid + along * 30.0);
        let (c, d) = (b + up * width, a + up * width);
        quad(&mut t, a, b, c, d);
    }
    mesh.add_triangles(
        t,
        Material::lambert([0.7, 0.7, 0.75])?,
        Some("panels".into()),
    )?;

    let count = ((COUNT as f32 * detail).round() as usize).max(1);
    let mut t = Vec::new();
    for i in 0..count {
        let u = |d: u64| uniform(seed, i as u64, 0, d);
        let r = 0.02 + 0.08 * u(0);
        let at = Vec3::new(20.0 * (u(1) - 0.5), r * 0.9, 20.0 * (u(2) - 0.5));
        icosphere(&mut t, at, r, 2);
    }
    mesh.add_triangles(
        t,
        Material::lambert([0.3, 0.28, 0.25])?,
        Some("pebbles".into()),
    )?;
    let cam = camera([3.0, 2.5, 12.0], [0.0, 0.2, 0.0], 55.0)?;
    Ok(setup("panels", mesh, cam, daylight(30.0, 55.0)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::testing::{check_basic, check_seeds};

    #[test]
    fn builds_deterministically() {
        let s = build(1.0, 1).unwrap();
        check_basic(&s, "panels", 64_000..=64_100);
        check_seeds(build, 0.5, true);
    }
}
