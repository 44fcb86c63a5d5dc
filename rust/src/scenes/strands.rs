//! `strands`: a stand of long, thin, leaning reeds.
//!
//! **Purpose.** Long thin triangles (a strand's segment is 25 cm long and 6 mm wide) at
//! random slants: each triangle's bounding box is mostly empty, the case that splits badly
//! in a BVH. Unlike `garden`'s short blades, the strands are as tall as the camera and
//! cross each other: 47% of ground rays are blocked (those from inside the stand nearly
//! all).
//!
//! **World** (metres, ground at y = 0):
//! - `ground`: a 30 x 30 m square, cells of 1 m / sqrt(detail).
//! - `strands`: [`COUNT`] reeds rooted at uniform random points of a disc of radius 3 m,
//!   each 1.2 to 2.2 m long, leaning by up to 35° in a random direction and curving
//!   further over as it rises, made of [`SEGMENTS`] segments (two triangles each) of
//!   width 6 mm tapering to 1 mm at the tip, turned to a random azimuth.
//!
//! **Triangles.** 241,800 at detail 1 (strands and ground scale with detail).
//!
//! **Camera.** Eye (0, 1.4, 6.5) looking at (0, 0.9, 0): the edge of the stand and into it.
//!
//! **Environment.** [`super::daylight`], sun at azimuth 200°, elevation 30°.
//!
//! **Randomness.** `seed` fixes every root, length, lean, curve and azimuth.

use glam::Vec3;

use super::shapes::{ground, strip, uniform};
use super::{camera, check_detail, daylight, setup, Setup};
use crate::bsdf::Material;
use crate::error::Result;
use crate::geometry::Mesh;

/// Strands at detail 1.
pub const COUNT: usize = 20_000;

/// Segments per strand.
pub const SEGMENTS: usize = 6;

/// Builds the setup (see the module docs).
pub fn build(detail: f32, seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    let mut mesh = Mesh::new();
    let mut t = Vec::new();
    ground(
        &mut t,
        Vec3::ZERO,
        30.0,
        (30.0 * detail.sqrt()).ceil() as usize,
    );
    mesh.add_triangles(
        t,
        Material::lambert([0.4, 0.33, 0.25])?,
        Some("ground".into()),
    )?;

    let count = ((COUNT as f32 * detail).round() as usize).max(1);
    let mut t = Vec::with_capacity(count * 2 * SEGMENTS);
    for i in 0..count {
        let u = |d: u64| uniform(seed, i as u64, 0, d);
        let (r, a) = (3.0 * u(0).sqrt(), std::f32::consts::TAU * u(1));
        let root = Vec3::new(r * a.cos(), 0.0, r * a.sin());
        let length = 1.2 + u(2);
        let lean = 35f32.to_radians() * u(3);
        let lean_dir = std::f32::consts::TAU * u(4);
        let bend = 0.6 * u(5);
        let facing = std::f32::consts::TAU * u(6);
        let horizontal = Vec3::new(lean_dir.cos(), 0.0, lean_dir.sin());
        let mut spine = Vec::with_capacity(SEGMENTS + 1);
        let mut widths = Vec::with_capacity(SEGMENTS + 1);
        let mut p = root;
        for k in 0..=SEGMENTS {
            let f = k as f32 / SEGMENTS as f32;
            spine.push(p);
            widths.push(0.003 * (1.0 - f) + 0.0005 * f);
            let angle = lean + bend * f;
            p += (Vec3::Y * angle.cos() + horizontal * angle.sin()) * (length / SEGMENTS as f32);
        }
        strip(
            &mut t,
            &spine,
            &widths,
            Vec3::new(facing.cos(), 0.0, facing.sin()),
        );
    }
    mesh.add_triangles(
        t,
        Material::lambert([0.55, 0.5, 0.3])?,
        Some("strands".into()),
    )?;
    let cam = camera([0.0, 1.4, 6.5], [0.0, 0.9, 0.0], 50.0)?;
    Ok(setup("strands", mesh, cam, daylight(200.0, 30.0)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::testing::{check_basic, check_scaling, check_seeds};

    #[test]
    fn builds_deterministically_and_scales() {
        let s = build(0.1, 1).unwrap();
        check_basic(&s, "strands", 24_000..=24_400);
        check_seeds(build, 0.05, true);
        check_scaling(build, 0.1);
    }
}
