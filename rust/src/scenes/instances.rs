//! `instances`: hundreds of randomly rotated solids over a large ground.
//!
//! **Purpose.** A benchmark scene unlike the built-ins: many mid-sized closed objects at
//! random orientations, so boxes of the BVH overlap at every level and ground rays are
//! blocked in every direction near the horizon (about 60% of ground rays). Shadows of all
//! sizes; the camera sees a crowded field.
//!
//! **World** (metres, ground at y = 0):
//! - `ground`: a 40 x 40 m square centred at the origin, cells of 1 m / sqrt(detail).
//! - `spheres`, `cylinders`, `boxes`: [`COUNT`] solids (a third of each kind, by index)
//!   at uniform random positions in the central 36 x 36 m, each of size 0.4 to 1.6 m,
//!   turned by a uniform random rotation and lifted so that it rests on (or just in) the
//!   ground. Spheres are icospheres of level 3 (1,280 triangles), cylinders capped tubes of
//!   24 sides, boxes cut into cells of 0.25 m (the number of solids scales with detail).
//!
//! **Triangles.** 210,904 at detail 1 (the count of solids scales with detail).
//!
//! **Camera.** Eye (0, 5, 22) looking at (0, 0.5, 4), vertical field of view 45 degrees.
//!
//! **Environment.** [`super::daylight`], sun at azimuth 135°, elevation 40°.
//!
//! **Randomness.** `seed` fixes every position, size, rotation and kind.

use glam::{Quat, Vec3};

use super::shapes::{ground, icosphere, tube, uniform, BoxGrid, Tri};
use super::{camera, check_detail, daylight, setup, Setup};
use crate::bsdf::Material;
use crate::error::Result;
use crate::geometry::Mesh;

/// Solids at detail 1.
pub const COUNT: usize = 400;

/// Builds the setup (see the module docs).
pub fn build(detail: f32, seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    let s = detail.sqrt();
    let mut mesh = Mesh::new();
    let mut t = Vec::new();
    ground(
        &mut t,
        Vec3::ZERO,
        40.0,
        (40.0 * s).ceil().max(1.0) as usize,
    );
    mesh.add_triangles(
        t,
        Material::lambert([0.55, 0.53, 0.5])?,
        Some("ground".into()),
    )?;

    let count = ((COUNT as f32 * detail).round() as usize).max(3);
    // The solids keep their tessellation; their number scales with detail.
    let (ico_level, sides, cell) = (3, 24, 0.25);
    let mut kinds: [Vec<Tri>; 3] = Default::default();
    for i in 0..count {
        let u = |d: u64| uniform(seed, i as u64, 0, d);
        let size = 0.4 + 1.2 * u(0);
        let at = Vec3::new(36.0 * (u(1) - 0.5), 0.0, 36.0 * (u(2) - 0.5));
        let rotation = random_rotation(u(3), u(4), u(5));
        let mut local = Vec::new();
        let kind = i % 3;
        match kind {
            0 => icosphere(&mut local, Vec3::ZERO, 0.5 * size, ico_level),
            1 => {
                let h = 0.5 * size;
                tube(
                    &mut local,
                    &[Vec3::new(0.0, -h, 0.0), Vec3::new(0.0, h, 0.0)],
                    0.25 * size,
                    sides,
                    true,
                );
            }
            _ => BoxGrid::new(
                Vec3::new(-0.5, -0.3, -0.4) * size,
                Vec3::new(0.5, 0.3, 0.4) * size,
                cell,
            )
            .closed(&mut local),
        }
        // Rest on the ground: the lowest rotated vertex at y = -2 cm.
        let lowest = local
            .iter()
            .flatten()
            .map(|v| (rotation * *v).y)
            .fold(f32::INFINITY, f32::min);
        let offset = at + Vec3::Y * (-lowest - 0.02);
        kinds[kind].extend(local.iter().map(|t| t.map(|v| rotation * v + offset)));
    }
    let [spheres, cylinders, boxes] = kinds;
    mesh.add_triangles(
        spheres,
        Material::phong([0.5, 0.2, 0.15], [0.3; 3], 40.0)?,
        Some("spheres".into()),
    )?;
    mesh.add_triangles(
        cylinders,
        Material::lambert([0.3, 0.5, 0.7])?,
        Some("cylinders".into()),
    )?;
    mesh.add_triangles(
        boxes,
        Material::lambert([0.75, 0.7, 0.45])?,
        Some("boxes".into()),
    )?;
    let cam = camera([0.0, 5.0, 22.0], [0.0, 0.5, 4.0], 45.0)?;
    Ok(setup("instances", mesh, cam, daylight(135.0, 40.0)?))
}

/// A uniform random rotation from three uniforms (Shoemake, "Uniform random rotations",
/// Graphics Gems III, 1992).
pub fn random_rotation(u1: f32, u2: f32, u3: f32) -> Quat {
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let (s2, c2) = (std::f32::consts::TAU * u2).sin_cos();
    let (s3, c3) = (std::f32::consts::TAU * u3).sin_cos();
    Quat::from_xyzw(a * s2, a * c2, b * s3, b * c3).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::testing::{check_basic, check_scaling, check_seeds};

    #[test]
    fn builds_deterministically_and_scales() {
        let s = build(0.25, 1).unwrap();
        check_basic(&s, "instances", 52_000..=53_000);
        check_seeds(build, 0.1, true);
        check_scaling(build, 0.25);
    }
}
