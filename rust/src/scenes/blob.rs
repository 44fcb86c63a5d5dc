//! `blob`: one dense, closed, bumpy mesh on a ground.
//!
//! **Purpose.** A single object of hundreds of thousands of small triangles: a deep BVH
//! over one closed surface whose bumps shadow each other at many scales. The ground around
//! it is mostly open (31% of ground rays blocked, most of them near the blob).
//!
//! **World** (metres, ground at y = 0):
//! - `ground`: 20 x 20 m, cells of 0.5 m / sqrt(detail).
//! - `blob`: an icosphere of radius 1.5 m at (0, 1.6, 0), subdivision level 7 +
//!   round(log4(detail)) (327,680 triangles at level 7), every vertex pushed along its
//!   direction by a sum of six sines of random frequencies (2 to 9 per radian) and phases,
//!   of total amplitude 25 cm; glossy.
//!
//! **Triangles.** 330,880 at detail 1 (3,200 of them the ground's).
//!
//! **Camera.** Eye (3.5, 2.6, 4.5) looking at (0, 1.3, 0), vertical field of view 45
//! degrees.
//!
//! **Environment.** [`super::daylight`], sun at azimuth 60°, elevation 50°.
//!
//! **Randomness.** `seed` fixes the bumps.

use glam::Vec3;

use super::shapes::{bumpy_ellipsoid, ground, MAX_ICO_LEVEL};
use super::{camera, check_detail, daylight, setup, Setup};
use crate::bsdf::Material;
use crate::error::Result;
use crate::geometry::Mesh;

/// Builds the setup (see the module docs).
pub fn build(detail: f32, seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    let mut mesh = Mesh::new();
    let mut t = Vec::new();
    ground(
        &mut t,
        Vec3::ZERO,
        20.0,
        (40.0 * detail.sqrt()).ceil() as usize,
    );
    mesh.add_triangles(
        t,
        Material::lambert([0.5, 0.5, 0.47])?,
        Some("ground".into()),
    )?;

    let center = Vec3::new(0.0, 1.6, 0.0);
    let level = (7.0 + detail.log(4.0).round()).clamp(1.0, MAX_ICO_LEVEL as f32) as u32;
    let mut t = Vec::new();
    bumpy_ellipsoid(&mut t, center, Vec3::splat(1.5), level, 0.25 / 1.5, seed);
    mesh.add_triangles(
        t,
        Material::phong([0.55, 0.45, 0.35], [0.3; 3], 30.0)?,
        Some("blob".into()),
    )?;
    let cam = camera([3.5, 2.6, 4.5], [0.0, 1.3, 0.0], 45.0)?;
    Ok(setup("blob", mesh, cam, daylight(60.0, 50.0)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::testing::{check_basic, check_scaling, check_seeds};

    #[test]
    fn builds_deterministically_and_scales() {
        let s = build(0.25, 1).unwrap();
        check_basic(&s, "blob", 82_000..=83_000);
        check_seeds(build, 0.0625, true);
        check_scaling(build, 1.0 / 16.0);
    }
}
