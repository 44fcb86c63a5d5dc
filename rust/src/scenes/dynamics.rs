//! `dynamics`: a few simple objects on a large plane.
//!
//! **Purpose.** Little occlusion: most points see most of the sky, and what blocks it
//! are a few large, smooth shapes. The easy case for caching, and a base for experiments
//! that move objects (each object is separate and named, so it can be moved or removed).
//!
//! **World** (metres, ground at y = 0):
//! - `ground`: a 300 x 300 m square centred at the origin (it reaches the camera's
//!   horizon), normal +y; cells of at most 1.35 m / sqrt(detail) over the central
//!   40 x 40 m, growing 1.5 times per step outside it.
//! - `box_large`: a 1.5 m cube centred at (-2, 0.75, -0.5), turned 20 degrees about +y.
//! - `box_flat`: 1 x 0.6 x 2 m (x, y, z) centred at (1.8, 0.3, 1.2), turned -35 degrees.
//! - `pillar`: 0.5 x 2.5 x 0.5 m centred at (0.6, 1.25, -2.5).
//! - `sphere`: an icosphere of radius 0.8 resting on the ground at (0.2, 0.8, 0.6), glossy.
//!
//! All objects are closed with outward normals.
//!
//! **Triangles.** The boxes are cut into cells of 0.25 m / sqrt(detail); the sphere has
//! subdivision level 3 + round(log4(detail)) (1,280 triangles at level 3): 6,768
//! triangles at detail 1 (4,608 for the ground, 880 for the boxes).
//!
//! **Camera.** Eye (5, 4.5, 7) looking down at (0, 0.4, 0), vertical field of view 38
//! degrees, 256 x 192: all four objects and the plane around them; every pixel sees the
//! plane or an object. The seed is unused: the scene has no randomness.
//!
//! **Environment.** [`super::daylight`] with the sun at azimuth 300°, elevation 45° (up
//! and behind the objects as the camera sees them, toward -x -z), so every object casts
//! a shadow toward the camera onto the plane.

use glam::Vec3;

use super::shapes::{graded, ground_lattice, icosphere, BoxGrid, MAX_ICO_LEVEL};
use super::{camera, check_detail, setup, Setup};
use crate::bsdf::Material;
use crate::error::Result;
use crate::geometry::Mesh;
use crate::lights::EnvMap;

/// Builds the setup (see the module docs). `seed` is unused.
pub fn build(detail: f32, _seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    let s = detail.sqrt();
    let mut mesh = Mesh::new();

    let mut t = Vec::new();
    let xs = graded(20.0, 1.35 / s, 150.0, 1.5);
    ground_lattice(&mut t, &xs, &xs, 0.0);
    mesh.add_triangles(
        t,
        Material::lambert([0.6, 0.58, 0.52])?,
        Some("ground".into()),
    )?;

    let cell = 0.25 / s;
    let boxes = [
        (
            "box_large",
            Vec3::new(-2.0, 0.75, -0.5),
            Vec3::splat(1.5),
            20f32,
            [0.7, 0.35, 0.15],
        ),
        (
            "box_flat",
            Vec3::new(1.8, 0.3, 1.2),
            Vec3::new(1.0, 0.6, 2.0),
            -35.0,
            [0.2, 0.35, 0.65],
        ),
        (
            "pillar",
            Vec3::new(0.6, 1.25, -2.5),
            Vec3::new(0.5, 2.5, 0.5),
            0.0,
            [0.75, 0.75, 0.72],
        ),
    ];
    for (name, center, size, yaw, albedo) in boxes {
        let mut t = Vec::new();
        BoxGrid::centered(center, size, yaw.to_radians(), cell).closed(&mut t);
        mesh.add_triangles(t, Material::lambert(albedo)?, Some(name.into()))?;
    }

    let level = (3.0 + detail.log(4.0).round()).clamp(1.0, MAX_ICO_LEVEL as f32) as u32;
    let mut t = Vec::new();
    icosphere(&mut t, Vec3::new(0.2, 0.8, 0.6), 0.8, level);
    mesh.add_triangles(
        t,
        Material::phong([0.45, 0.45, 0.5], [0.4; 3], 200.0)?,
        Some("sphere".into()),
    )?;

    let cam = camera([5.0, 4.5, 7.0], [0.0, 0.4, 0.0], 38.0)?;
    Ok(setup("dynamics", mesh, cam, envmap()?))
}

/// The default environment: sky and sun (see the module docs).
pub fn envmap() -> Result<EnvMap> {
    super::daylight(300.0, 45.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::testing::*;

    #[test]
    fn loads_with_documented_size() {
        let s = build(1.0, 0).unwrap();
        check_basic(&s, "dynamics", 6768..=6768);
        let b = s.scene.bounds();
        assert_eq!(b.min, Vec3::new(-150.0, 0.0, -150.0));
        assert_eq!(b.max, Vec3::new(150.0, 2.5, 150.0));
        check_seeds(build, 1.0, false);
        check_scaling(build, 1.0);
    }

    #[test]
    fn little_occlusion() {
        let s = build(1.0, 0).unwrap();
        let c = &s.camera;
        let mut counters = crate::geometry::TraversalCounters::default();
        let (mut sum, mut n) = (0.0, 0);
        for y in 0..6 {
            for x in 0..8 {
                let d = c.direction((x as f32 + 0.5) * 32.0, (y as f32 + 0.5) * 32.0);
                let h = s.scene.intersect1(c.eye, d, f32::INFINITY, &mut counters);
                let h = h.expect("every sampled pixel hits");
                let nrm = if h.normal.dot(d) > 0.0 {
                    -h.normal
                } else {
                    h.normal
                };
                sum += occluded_fraction(&s.scene, h.position, nrm, 64);
                n += 1;
            }
        }
        assert!(sum / (n as f32) < 0.25, "mean occlusion {}", sum / n as f32);
    }
}
