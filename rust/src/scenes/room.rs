//! `room`: a closed room seen from inside, lit through its windows.
//!
//! **Purpose.** The environment reaches the inside only through a few openings: about 95%
//! of the floor's hemisphere is blocked, and which part of the sky a point sees through the
//! windows changes smoothly across the floor. Unlike `cornell` (closed, lit by an area
//! light), the light here is the environment's: the case where visibility decides nearly
//! everything and the sun falls through a window onto the floor. 95% of ground (floor)
//! rays are blocked.
//!
//! **World** (metres; floor at y = 0; walls 0.2 m thick):
//! - `ground`: the floor, x in [-4, 4], z in [-3, 3], cells of 0.25 m / sqrt(detail), and
//!   `ceiling` at y = 3.
//! - `walls`: the four walls (boxes around their openings): the back wall (z = -3) has two
//!   windows 1.4 m wide from 0.9 to 2.3 m high, the left wall (x = -4) one window 2 m wide,
//!   the right wall (x = 4) a door 1 m wide and 2.1 m high.
//! - `table` (a top on four legs), `shelf` (a tall box against the right wall), `sofa`
//!   (two boxes), cut into cells of 0.1 m / sqrt(detail).
//!
//! **Camera.** Inside, by the front wall: eye (0.5, 1.6, 2.6) looking at (-0.5, 0.8, -2),
//! vertical field of view 60 degrees.
//!
//! **Environment.** [`super::daylight`] with the sun at azimuth 340°, elevation 30°: it
//! shines in through the back windows onto the floor. The seed is unused.
//!
//! **Variant `sunlit`** ([`build_sunlit`], see [`super::load_variant`]): a sun-lit
//! interior where indirect light dominates. The same geometry under [`super::daylight`]
//! with the sun higher and behind the back wall ([`SUNLIT_AZIMUTH_DEG`] = 350°,
//! [`SUNLIT_ELEVATION_DEG`] = 45°): through the two back windows it lights two patches of
//! the floor, z from about -2.1 to -0.7. The camera stands by the back wall between the
//! windows, eye (0.5, 1.5, -2.7), and looks across the room at (0, 1.2, 3) (vertical field
//! of view 60°): it sees the front wall, the sofa, the table, floor and ceiling, but
//! neither a window, the door nor the patches, so most of what it sees is lit by the
//! patches' bounce. At 128 x 96, 70% of the image's energy is indirect
//! (`method="path", bounces=3`; see [`super`]'s table).

use glam::Vec3;

use super::shapes::{cells, grid, wall_pieces, BoxGrid, Opening};
use super::{camera, check_detail, daylight, setup, Setup};
use crate::bsdf::Material;
use crate::error::Result;
use crate::geometry::Mesh;

/// A piece of furniture: its name, its boxes (min and max corners) and its albedo.
type Furniture<'a> = (&'a str, &'a [(Vec3, Vec3)], [f32; 3]);

/// Builds the setup (see the module docs). `seed` is unused.
pub fn build(detail: f32, _seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    let s = detail.sqrt();
    let cell = 0.25 / s;
    let mut mesh = Mesh::new();
    let (x0, x1, z0, z1, top) = (-4.0f32, 4.0f32, -3.0f32, 3.0f32, 3.0f32);
    let wall = 0.2;
    let mut t = Vec::new();
    // The floor faces up (ground rays start on it); the ceiling is a slab.
    grid(
        &mut t,
        Vec3::new(x0, 0.0, z0),
        Vec3::Z * (z1 - z0),
        Vec3::X * (x1 - x0),
        cells(z1 - z0, cell),
        cells(x1 - x0, cell),
    );
    mesh.add_triangles(
        t,
        Material::lambert([0.6, 0.5, 0.4])?,
        Some("ground".into()),
    )?;
    let mut t = Vec::new();
    BoxGrid::new(Vec3::new(x0, top, z0), Vec3::new(x1, top + wall, z1), cell).closed(&mut t);
    mesh.add_triangles(
        t,
        Material::lambert([0.85, 0.85, 0.82])?,
        Some("ceiling".into()),
    )?;

    let mut pieces = Vec::new();
    let window = |u0: f32, u1: f32| Opening {
        u: [u0, u1],
        v: [0.9, 2.3],
    };
    // Back (z = -3) and front (z = 3) walls along x; left and right along z.
    pieces.extend(wall_pieces(
        0,
        [x0 - wall, x1 + wall],
        [0.0, top],
        [z0 - wall, z0],
        &[window(-2.7, -1.3), window(0.5, 1.9)],
    ));
    pieces.extend(wall_pieces(
        0,
        [x0 - wall, x1 + wall],
        [0.0, top],
        [z1, z1 + wall],
        &[],
    ));
    pieces.extend(wall_pieces(
        2,
        [z0, z1],
        [0.0, top],
        [x0 - wall, x0],
        &[window(-1.0, 1.0)],
    ));
    pieces.extend(wall_pieces(
        2,
        [z0, z1],
        [0.0, top],
        [x1, x1 + wall],
        &[Opening {
            u: [0.8, 1.8],
            v: [0.0, 2.1],
        }],
    ));
    let mut t = Vec::new();
    for (lo, hi) in pieces {
        BoxGrid::new(lo, hi, cell).closed(&mut t);
    }
    mesh.add_triangles(
        t,
        Material::lambert([0.8, 0.78, 0.72])?,
        Some("walls".into()),
    )?;

    let fine = 0.1 / s;
    let furniture: [Furniture<'_>; 3] = [
        (
            "table",
            &[
                (Vec3::new(-1.6, 0.72, -1.2), Vec3::new(0.0, 0.78, -0.2)),
                (Vec3::new(-1.55, 0.0, -1.15), Vec3::new(-1.45, 0.72, -1.05)),
                (Vec3::new(-0.15, 0.0, -1.15), Vec3::new(-0.05, 0.72, -1.05)),
                (Vec3::new(-1.55, 0.0, -0.35), Vec3::new(-1.45, 0.72, -0.25)),
                (Vec3::new(-0.15, 0.0, -0.35), Vec3::new(-0.05, 0.72, -0.25)),
            ],
            [0.45, 0.3, 0.18],
        ),
        (
            "shelf",
            &[(Vec3::new(3.4, 0.0, -2.6), Vec3::new(4.0, 2.2, -1.2))],
            [0.35, 0.4, 0.45],
        ),
        (
            "sofa",
            &[
                (Vec3::new(-3.9, 0.0, 0.3), Vec3::new(-3.0, 0.45, 2.4)),
                (Vec3::new(-3.9, 0.45, 0.3), Vec3::new(-3.6, 0.9, 2.4)),
            ],
            [0.6, 0.15, 0.15],
        ),
    ];
    for (name, boxes, albedo) in furniture {
        let mut t = Vec::new();
        for (lo, hi) in boxes {
            BoxGrid::new(*lo, *hi, fine).closed(&mut t);
        }
        mesh.add_triangles(t, Material::lambert(albedo)?, Some(name.into()))?;
    }
    let cam = camera([0.5, 1.6, 2.6], [-0.5, 0.8, -2.0], 60.0)?;
    Ok(setup("room", mesh, cam, daylight(340.0, 30.0)?))
}

/// Azimuth of the `sunlit` variant's sun, degrees (behind the back wall, z < 0).
pub const SUNLIT_AZIMUTH_DEG: f32 = 350.0;
/// Elevation of the `sunlit` variant's sun, degrees.
pub const SUNLIT_ELEVATION_DEG: f32 = 45.0;

/// The `sunlit` variant (see the module docs): the default geometry, the sun at
/// [`SUNLIT_AZIMUTH_DEG`], [`SUNLIT_ELEVATION_DEG`] and a camera that sees neither the
/// windows nor the sun patches. `seed` is unused.
pub fn build_sunlit(detail: f32, seed: u64) -> Result<Setup> {
    let mut s = build(detail, seed)?;
    s.envmap = daylight(SUNLIT_AZIMUTH_DEG, SUNLIT_ELEVATION_DEG)?;
    s.camera = camera([0.5, 1.5, -2.7], [0.0, 1.2, 3.0], 60.0)?;
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::TraversalCounters;
    use crate::lights::procedural;
    use crate::scenes::testing::{check_basic, check_scaling, check_seeds};

    #[test]
    fn sunlit_variant_hides_the_sun_patches_and_the_windows() {
        let s = crate::scenes::load_variant("room", Some("sunlit"), 0.5, 0).unwrap();
        assert_eq!(s.variant.as_deref(), Some("sunlit"));
        check_basic(&s, "room", 9_000..=9_300);
        check_seeds(build_sunlit, 0.25, false);
        let sun = procedural::direction(SUNLIT_AZIMUTH_DEG, SUNLIT_ELEVATION_DEG);
        let mut c = TraversalCounters::default();
        let lit = |p: Vec3, n: Vec3, c: &mut _| {
            n.dot(sun) > 1e-3
                && !s
                    .scene
                    .occluded1(s.scene.offset_point(p, n), sun, f32::INFINITY, c)
        };
        // The sun falls through both back windows onto the floor (0.1 m grid over the room).
        let mut patch = Vec::new();
        for i in 0..80 {
            for j in 0..60 {
                let p = Vec3::new(
                    -4.0 + 0.1 * (i as f32 + 0.5),
                    0.0,
                    -3.0 + 0.1 * (j as f32 + 0.5),
                );
                if lit(p, Vec3::Y, &mut c) {
                    patch.push(p);
                }
            }
        }
        let area = patch.len() as f32 * 0.01;
        assert!(area > 2.5 && area < 4.5, "sun patches: {area} m²");
        assert!(patch.iter().all(|p| p.z > -2.3 && p.z < -0.5));
        assert!(patch.iter().any(|p| p.x < -1.0) && patch.iter().any(|p| p.x > 0.0));
        // Every pixel of a 64 x 48 grid sees a surface of the room that the sun misses.
        let cam = &s.camera;
        for y in 0..48 {
            for x in 0..64 {
                let d = cam.direction((x as f32 + 0.5) * 4.0, (y as f32 + 0.5) * 4.0);
                let h = s
                    .scene
                    .intersect1(cam.eye, d, f32::INFINITY, &mut c)
                    .unwrap_or_else(|| panic!("pixel ({x}, {y}) sees the sky"));
                let n = if h.normal.dot(d) > 0.0 {
                    -h.normal
                } else {
                    h.normal
                };
                assert!(
                    !lit(h.position, n, &mut c),
                    "pixel ({x}, {y}) sees sun at {}",
                    h.position
                );
            }
        }
    }

    #[test]
    fn builds_deterministically_and_scales() {
        let s = build(0.5, 1).unwrap();
        check_basic(&s, "room", 9_000..=9_300);
        check_seeds(build, 0.25, false);
        check_scaling(build, 0.5);
    }
}
