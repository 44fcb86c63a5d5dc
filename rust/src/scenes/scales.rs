//! `scales`: a kilometre of ground with centimetre parts in front of the camera.
//!
//! **Purpose.** Mixed scales: a 1 km ground and towers tens of metres high far away, and
//! a board of components 1 to 5 cm across half a metre from the camera. Ray epsilons,
//! BVH boxes and cache radii must work at both scales at once. Ground rays are almost all
//! unblocked (12% blocked).
//!
//! **World** (metres, ground at y = 0):
//! - `ground`: 1000 x 1000 m, cells of 0.5 m / sqrt(detail) over the central 4 x 4 m,
//!   growing 1.6 times per step outside.
//! - `board`: a 0.5 x 0.01 x 0.4 m slab on the ground at the origin.
//! - `parts`: [`COUNT`] boxes 1 to 5 cm wide and 0.5 to 3 cm high standing on the board at
//!   random places and yaws.
//! - `towers`: 12 boxes 10 to 30 m wide and 20 to 120 m high, 150 to 450 m away.
//!
//! **Triangles.** 29,152 at detail 1.
//!
//! **Camera.** Eye (0, 0.22, 0.5) looking at (0, 0.0, -0.05), vertical field of view 55
//! degrees: the board fills the lower half, the horizon and towers the upper.
//!
//! **Environment.** [`super::daylight`], sun at azimuth 250°, elevation 35°.
//!
//! **Randomness.** `seed` fixes the parts and towers.

use glam::Vec3;

use super::shapes::{graded, ground_lattice, uniform, BoxGrid};
use super::{camera, check_detail, daylight, setup, Setup};
use crate::bsdf::Material;
use crate::error::Result;
use crate::geometry::Mesh;

/// Parts on the board at detail 1.
pub const COUNT: usize = 2000;

/// Builds the setup (see the module docs).
pub fn build(detail: f32, seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    let s = detail.sqrt();
    let mut mesh = Mesh::new();
    let mut t = Vec::new();
    let xs = graded(2.0, 0.5 / s, 500.0, 1.6);
    ground_lattice(&mut t, &xs, &xs, 0.0);
    mesh.add_triangles(
        t,
        Material::lambert([0.45, 0.5, 0.4])?,
        Some("ground".into()),
    )?;

    let mut t = Vec::new();
    BoxGrid::new(
        Vec3::new(-0.25, 0.0, -0.2),
        Vec3::new(0.25, 0.01, 0.2),
        0.05,
    )
    .closed(&mut t);
    mesh.add_triangles(
        t,
        Material::lambert([0.1, 0.35, 0.15])?,
        Some("board".into()),
    )?;

    let count = ((COUNT as f32 * detail).round() as usize).max(1);
    let mut t = Vec::new();
    for i in 0..count {
        let u = |d: u64| uniform(seed, i as u64, 0, d);
        let w = 0.01 + 0.04 * u(0);
        let d = 0.01 + 0.04 * u(1);
        let h = 0.005 + 0.025 * u(2);
        let at = Vec3::new(0.46 * (u(3) - 0.5), 0.01 + 0.5 * h, 0.36 * (u(4) - 0.5));
        BoxGrid::centered(at, Vec3::new(w, h, d), std::f32::consts::TAU * u(5), 1.0).closed(&mut t);
    }
    mesh.add_triangles(
        t,
        Material::phong([0.4, 0.4, 0.42], [0.4; 3], 60.0)?,
        Some("parts".into()),
    )?;

    let mut t = Vec::new();
    for i in 0..12u64 {
        let u = |d: u64| uniform(seed, i, 1, d);
        let (r, a) = (150.0 + 300.0 * u(0), std::f32::consts::TAU * u(1));
        let (w, h) = (10.0 + 20.0 * u(2), 20.0 + 100.0 * u(3));
        let at = Vec3::new(r * a.cos(), 0.5 * h, r * a.sin());
        BoxGrid::centered(at, Vec3::new(w, h, w), a, 10.0).closed(&mut t);
    }
    mesh.add_triangles(
        t,
        Material::lambert([0.6, 0.6, 0.62])?,
        Some("towers".into()),
    )?;
    let cam = camera([0.0, 0.22, 0.5], [0.0, 0.0, -0.05], 55.0)?;
    Ok(setup("scales", mesh, cam, daylight(250.0, 35.0)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::testing::{check_basic, check_seeds};

    #[test]
    fn ray_offsets_stay_below_the_parts_size() {
        // The shadow-ray offset at a hit on the board is a few micrometres (64 ulps of the
        // hit triangle's coordinates), and the point-only offset a fraction of a
        // millimetre: both far below the 5 mm of the lowest parts (the scene-size offset
        // this replaced was 11 mm, and lit the parts' contact shadows).
        use crate::geometry::TraversalCounters;
        let s = build(0.25, 1).unwrap();
        let c = &s.camera;
        let d = c.direction(c.width as f32 * 0.5, c.height as f32 * 0.8);
        let hit = s
            .scene
            .intersect1(c.eye, d, f32::INFINITY, &mut TraversalCounters::default())
            .unwrap();
        assert!(hit.position.length() < 0.5, "{}", hit.position);
        assert!(
            s.scene.hit_epsilon(&hit) < 1e-5,
            "{}",
            s.scene.hit_epsilon(&hit)
        );
        assert!(s.scene.ray_epsilon(hit.position) < 5e-4);
    }

    #[test]
    fn builds_deterministically() {
        let s = build(0.25, 1).unwrap();
        check_basic(&s, "scales", 9_000..=10_000);
        check_seeds(build, 0.25, true);
    }
}
