//! `garage`: an open-fronted building under a deep roof overhang, with parked cars.
//!
//! **Purpose.** Points under the overhang see the bright sky only through a thin band
//! near the horizon (past the roof's front edge) and through a few openings, so most of
//! the environment is occluded and the visible part changes quickly with position: the
//! case where a visibility cache pays off most.
//!
//! **World** (metres; ground at y = 0, the open front faces +z):
//! - `ground`: a 60 x 60 m square centred at the origin, normal +y.
//! - Walls 3 m high and 0.25 m thick around the interior x in [-6, 6], z in [-4, 4]:
//!   `back_wall` (z in [-4.25, -4]) with a window and a door, `left_wall` (x < -6) with a
//!   window and `right_wall` (x > 6) with a door. The front (z = 4) is open. Each wall is a
//!   union of closed boxes (piers, sills, lintels) around its openings.
//! - `roof`: a closed slab x in [-7, 7], y in [3, 3.3], z in [-4.75, 10]: it overhangs the
//!   open front by 6 m and the other walls by 0.75 m; `post_left`/`post_right` (0.3 m
//!   square, 3 m high) carry its front corners.
//! - `car0`..`car3`: closed 4.5 x 1.8 x 1.5 m boxes (length along z), glossy (Phong),
//!   centred at x = -4, -1.8, 2.6, 4.6 and z = 3, 7, 5.5, 9.5 and turned 0, 3, -2 and 8
//!   degrees about +y: `car0` reaches into the building, `car3` sticks out beyond the
//!   roof's edge.
//!
//! Solids touch (wall pieces each other, walls the ground and the roof, cars the ground);
//! the coplanar faces where they touch lie inside solids and cannot be seen.
//!
//! **Triangles.** The ground is cut into cells of 1.2 m / sqrt(detail), everything else
//! into cells of 0.5 m / sqrt(detail): 11,636 triangles at detail 1 (5,000 for the
//! ground, 1,740 for the walls, 3,592 for the roof, 104 for the posts, 1,200 for the cars).
//!
//! **Camera.** A person standing outside, 3.5 m in front of the roof's edge: eye
//! (0, 1.6, 13.5) looking at (0, 0, 2.5) (the floor just inside the open front) between
//! the cars, vertical field of view 50 degrees, 256 x 192. The roof's underside fills the
//! top of the frame, the back wall with its openings the middle; only the bottom rows
//! (ground just outside the roof's edge) and the openings (sky) lie elsewhere. From the
//! centre pixel's point about 95% of the hemisphere is blocked. The seed is unused: the
//! scene has no randomness.
//!
//! **Environment.** [`envmap`]: three large, very bright windows on a dim blue background
//! (radiance 0.04-0.06), the kind of lighting of CAM08's garage. `high` (azimuth 150°-230°,
//! elevation 25°-65°, radiance 30) carries most of the power and is hidden by the roof from
//! everything under it; `low` (azimuth 155°-205°, elevation 3°-15°, radiance 20) shines
//! in under the roof's edge, between the cars, onto the floor the camera sees; `back`
//! (azimuth 300°-360°, elevation 5°-25°, radiance 25) reaches the floor through the back
//! and left walls' openings. From the centre pixel's point only a few percent of the
//! unoccluded irradiance arrives.
//!
//! The default map has no sun, and its windows light the back and side walls directly:
//! `low` reaches them under the roof's edge, so no floor patch dominates their light.
//!
//! **Variant `sun`** ([`build_sun`], see [`super::load_variant`]): the same geometry and
//! camera under [`super::daylight`] with a low sun straight in front
//! ([`SUN_AZIMUTH_DEG`] = 180°, toward +z; [`SUN_ELEVATION_DEG`] = 15°). The sun enters
//! through the open front under the roof's edge and lights a patch of the floor from
//! z ≈ -1.2 (where the ray past the edge at y = 3, z = 10 reaches the floor) to the front,
//! with the cars' shadows; it reaches neither the roof's underside nor the walls' inner
//! faces (the back wall lies beyond the patch, the side walls are parallel to the sun), so
//! they are lit by the patch's bounce and by the sky. The ground outside is sunlit too.
//!
//! **Variant `ceiling_lights`** ([`build_ceiling_lights`]): the same geometry and camera at
//! night ([`NIGHT_RADIANCE`], a dim constant map) lit by [`CEILING_LIGHTS`] small square
//! area lights (0.12 m, facing down, 5 mm under the roof's underside) on a 40 x 25 grid over
//! x in [-5.85, 5.85], z in [-3.8, 9.4]: inside the building and under the overhang. Their
//! radiances differ (a fixed scramble of the index between 0.25x and 1.75x of
//! [`CEILING_LIGHT_RADIANCE`]), so drawing lights by power differs from drawing them
//! uniformly. The many-light case of the survey's ch. 6: a point sees hundreds of lights,
//! the cars and walls hide many of them, and a few nearby ones dominate.

use glam::Vec3;

use super::shapes::{cells, ground, wall_pieces, BoxGrid, Opening};
use super::{camera, check_detail, setup, Setup};
use crate::bsdf::Material;
use crate::error::Result;
use crate::geometry::Mesh;
use crate::lights::procedural::{self, Window};
use crate::lights::EnvMap;

/// Height of the walls, and of the roof's underside (m).
pub const WALL_HEIGHT: f32 = 3.0;
/// z of the roof's front edge (m).
pub const ROOF_FRONT: f32 = 10.0;

/// Builds the setup (see the module docs). `seed` is unused.
pub fn build(detail: f32, _seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    let s = detail.sqrt();
    let cell = 0.5 / s;
    let mut mesh = Mesh::new();

    let mut t = Vec::new();
    let size = 60.0;
    ground(&mut t, Vec3::ZERO, size, cells(size, 1.2 / s));
    mesh.add_triangles(
        t,
        Material::lambert([0.35, 0.35, 0.33])?,
        Some("ground".into()),
    )?;

    let wall = Material::lambert([0.7, 0.68, 0.62])?;
    let (h, th) = (WALL_HEIGHT, 0.25);
    let v = [0.0, h];
    let walls = [
        (
            "back_wall",
            wall_pieces(
                0,
                [-6.0 - th, 6.0 + th],
                v,
                [-4.0 - th, -4.0],
                &[
                    Opening {
                        u: [-4.0, -2.0],
                        v: [1.0, 2.0],
                    },
                    Opening {
                        u: [2.5, 3.5],
                        v: [0.0, 2.1],
                    },
                ],
            ),
        ),
        (
            "left_wall",
            wall_pieces(
                2,
                [-4.0, 4.0],
                v,
                [-6.0 - th, -6.0],
                &[Opening {
                    u: [-1.5, 1.0],
                    v: [1.0, 2.0],
                }],
            ),
        ),
        (
            "right_wall",
            wall_pieces(
                2,
                [-4.0, 4.0],
                v,
                [6.0, 6.0 + th],
                &[Opening {
                    u: [-2.5, -1.5],
                    v: [0.0, 2.1],
                }],
            ),
        ),
    ];
    for (name, pieces) in walls {
        let mut t = Vec::new();
        for (lo, hi) in pieces {
            BoxGrid::new(lo, hi, cell).closed(&mut t);
        }
        mesh.add_triangles(t, wall, Some(name.into()))?;
    }

    let concrete = Material::lambert([0.55, 0.55, 0.52])?;
    let mut t = Vec::new();
    BoxGrid::new(
        Vec3::new(-7.0, h, -4.75),
        Vec3::new(7.0, h + 0.3, ROOF_FRONT),
        cell,
    )
    .closed(&mut t);
    mesh.add_triangles(t, concrete, Some("roof".into()))?;
    for (name, x) in [("post_left", -6.6), ("post_right", 6.6)] {
        let mut t = Vec::new();
        BoxGrid::centered(
            Vec3::new(x, h * 0.5, ROOF_FRONT - 0.4),
            Vec3::new(0.3, h, 0.3),
            0.0,
            cell,
        )
        .closed(&mut t);
        mesh.add_triangles(t, concrete, Some(name.into()))?;
    }

    let car = Vec3::new(1.8, 1.5, 4.5);
    let paints = [
        ([0.55, 0.05, 0.05], [0.3; 3], 60.0),
        ([0.05, 0.1, 0.45], [0.3; 3], 60.0),
        ([0.4, 0.4, 0.42], [0.45; 3], 120.0),
        ([0.65, 0.65, 0.62], [0.3; 3], 80.0),
    ];
    let places = [
        (-4.0, 3.0, 0.0f32),
        (-1.8, 7.0, 3.0),
        (2.6, 5.5, -2.0),
        (4.6, 9.5, 8.0),
    ];
    for (i, ((x, z, yaw), (kd, ks, e))) in places.into_iter().zip(paints).enumerate() {
        let mut t = Vec::new();
        BoxGrid::centered(Vec3::new(x, car.y * 0.5, z), car, yaw.to_radians(), cell).closed(&mut t);
        mesh.add_triangles(t, Material::phong(kd, ks, e)?, Some(format!("car{i}")))?;
    }

    let cam = camera([0.0, 1.6, 13.5], [0.0, 0.0, 2.5], 50.0)?;
    Ok(setup("garage", mesh, cam, envmap()?))
}

/// Azimuth of the `sun` variant's sun, degrees (180: in front of the open side, +z).
pub const SUN_AZIMUTH_DEG: f32 = 180.0;
/// Elevation of the `sun` variant's sun, degrees: low enough to pass under the roof's edge
/// into the building (below atan(3 / 6) ≈ 26.6° it reaches the floor inside).
pub const SUN_ELEVATION_DEG: f32 = 15.0;

/// The `sun` variant (see the module docs): the default geometry and camera lit by
/// [`super::daylight`] with the sun at [`SUN_AZIMUTH_DEG`], [`SUN_ELEVATION_DEG`]. `seed`
/// is unused.
pub fn build_sun(detail: f32, seed: u64) -> Result<Setup> {
    let mut s = build(detail, seed)?;
    s.envmap = super::daylight(SUN_AZIMUTH_DEG, SUN_ELEVATION_DEG)?;
    Ok(s)
}

/// Area lights of the `ceiling_lights` variant.
pub const CEILING_LIGHTS: usize = 1000;
/// Mean radiance of a ceiling light (W/(m² sr) per channel, warm white).
pub const CEILING_LIGHT_RADIANCE: [f32; 3] = [60.0, 52.0, 40.0];
/// Radiance of the `ceiling_lights` variant's night sky.
pub const NIGHT_RADIANCE: [f32; 3] = [0.01, 0.012, 0.02];

/// The `ceiling_lights` variant (see the module docs). `seed` is unused.
pub fn build_ceiling_lights(detail: f32, seed: u64) -> Result<Setup> {
    let mut s = build(detail, seed)?;
    s.envmap = EnvMap::constant(NIGHT_RADIANCE, super::ENV_RESOLUTION)?;
    let (nx, nz) = (40, 25);
    debug_assert_eq!(nx * nz, CEILING_LIGHTS);
    let (half, y) = (0.06, WALL_HEIGHT - 0.005);
    for i in 0..CEILING_LIGHTS {
        let x = -5.85 + 0.3 * (i % nx) as f32;
        let z = -3.8 + 0.55 * (i / nx) as f32;
        // A fixed scramble of the index (Knuth's multiplicative hash) in [0, 1).
        let u = ((i as u64 * 2_654_435_761) % 1000) as f32 / 1000.0;
        let radiance = CEILING_LIGHT_RADIANCE.map(|c| c * (0.25 + 1.5 * u));
        // Counter-clockwise seen from below: normal -y.
        let quad = [
            [x - half, y, z - half],
            [x + half, y, z - half],
            [x + half, y, z + half],
            [x - half, y, z + half],
        ];
        s.scene
            .add_area_light(&quad, radiance, Some(format!("ceiling_light{i}")))?;
    }
    Ok(s)
}

/// The default environment: bright windows, mostly occluded from under the roof (see the
/// module docs).
pub fn envmap() -> Result<EnvMap> {
    let window = |azimuth_deg, elevation_deg, width_deg, height_deg, radiance| Window {
        azimuth_deg,
        elevation_deg,
        width_deg,
        height_deg,
        radiance,
    };
    procedural::windows(
        &[
            window(190.0, 45.0, 80.0, 40.0, [30.0, 29.0, 27.0]),
            window(180.0, 9.0, 50.0, 12.0, [20.0, 19.0, 17.0]),
            window(330.0, 15.0, 60.0, 20.0, [25.0, 25.0, 26.0]),
        ],
        [0.04, 0.05, 0.06],
        super::ENV_RESOLUTION,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::testing::*;

    #[test]
    fn loads_with_documented_size() {
        let s = build(1.0, 0).unwrap();
        check_basic(&s, "garage", 11_636..=11_636);
        let b = s.scene.bounds();
        assert_eq!(b.min, Vec3::new(-30.0, 0.0, -30.0));
        assert_eq!(b.max, Vec3::new(30.0, 3.3, 30.0));
        check_seeds(build, 1.0, false);
        check_scaling(build, 1.0);
    }

    #[test]
    fn the_sky_is_mostly_occluded_from_what_the_camera_sees() {
        let s = build(1.0, 0).unwrap();
        let h = centre_hit(&s);
        assert_eq!(centre_object(&s), "ground");
        assert!(h.position.z < ROOF_FRONT);
        let f = occluded_fraction(&s.scene, h.position, Vec3::Y, 1000);
        assert!(f > 0.8, "centre: {f}");
        // Over the whole frame (coarse grid), most visible points are under the roof and
        // most of their sky is blocked.
        let c = &s.camera;
        let (mut sum, mut n, mut under) = (0.0, 0, 0);
        let mut counters = crate::geometry::TraversalCounters::default();
        for y in 0..6 {
            for x in 0..8 {
                let d = c.direction((x as f32 + 0.5) * 32.0, (y as f32 + 0.5) * 32.0);
                if let Some(h) = s.scene.intersect1(c.eye, d, f32::INFINITY, &mut counters) {
                    let nrm = if h.normal.dot(d) > 0.0 {
                        -h.normal
                    } else {
                        h.normal
                    };
                    sum += occluded_fraction(&s.scene, h.position, nrm, 64);
                    n += 1;
                    let p = h.position;
                    under += (p.z < ROOF_FRONT && p.y <= WALL_HEIGHT + 1e-3) as i32;
                }
            }
        }
        assert!(
            n >= 44,
            "{n} of 48 sampled pixels hit (the rest see sky through openings)"
        );
        assert!(under >= 36, "{under} of 48 under the roof");
        assert!(sum / n as f32 > 0.6, "mean occlusion {}", sum / n as f32);
    }

    #[test]
    fn the_ceiling_lights_variant_has_its_lights_under_the_roof_facing_down() {
        let s = crate::scenes::load_variant("garage", Some("ceiling_lights"), 0.25, 0).unwrap();
        let base = build(0.25, 0).unwrap();
        let lights = s.scene.area_lights();
        assert_eq!(lights.len(), CEILING_LIGHTS);
        assert_eq!(
            s.scene.num_objects(),
            base.scene.num_objects() + CEILING_LIGHTS
        );
        for l in lights {
            for t in l.triangles() {
                let n = (t[1] - t[0]).cross(t[2] - t[0]);
                assert!(n.y < 0.0 && n.x == 0.0 && n.z == 0.0, "{n}");
                for v in t {
                    assert!((v.y - (WALL_HEIGHT - 0.005)).abs() < 1e-6);
                    assert!(v.x.abs() < 6.0 && v.z > -4.0 && v.z < ROOF_FRONT);
                }
            }
        }
        // Radiances span the documented range, so power differs from uniform.
        let red: Vec<f32> = lights.iter().map(|l| l.radiance().x).collect();
        let (lo, hi) = red
            .iter()
            .fold((f32::MAX, 0.0f32), |(a, b), &r| (a.min(r), b.max(r)));
        let mean = CEILING_LIGHT_RADIANCE[0];
        assert!((0.25 * mean - 1e-3..0.3 * mean).contains(&lo), "{lo}");
        assert!(hi <= 1.75 * mean + 1e-3 && hi > 1.7 * mean, "{hi}");
    }

    #[test]
    fn the_sun_variant_lights_a_floor_patch_inside_but_not_the_walls() {
        let s = crate::scenes::load_variant("garage", Some("sun"), 1.0, 0).unwrap();
        let base = build(1.0, 0).unwrap();
        assert_eq!(s.variant.as_deref(), Some("sun"));
        assert_eq!(s.scene.mesh().triangles, base.scene.mesh().triangles);
        assert_eq!(s.camera, base.camera);
        let sun = procedural::direction(SUN_AZIMUTH_DEG, SUN_ELEVATION_DEG);
        let mut c = crate::geometry::TraversalCounters::default();
        let lit = |p: Vec3, n: Vec3, c: &mut _| {
            n.dot(sun) > 1e-3
                && !s
                    .scene
                    .occluded1(s.scene.offset_point(p, n), sun, f32::INFINITY, c)
        };
        // The floor inside the building (x in [-6, 6], z in [-4, 4]) on a 0.25 m grid: the
        // sun reaches it from z ≈ -1.2 on, outside the cars' long shadows (measured: 31%
        // of the floor inside), never behind that.
        let (mut lit_floor, mut inside) = (0, 0);
        for i in 0..48 {
            for j in 0..32 {
                let p = Vec3::new(
                    -6.0 + 0.25 * (i as f32 + 0.5),
                    0.0,
                    -4.0 + 0.25 * (j as f32 + 0.5),
                );
                inside += 1;
                if lit(p, Vec3::Y, &mut c) {
                    lit_floor += 1;
                    assert!(p.z > -1.3, "sunlit floor at {p}");
                }
            }
        }
        let f = lit_floor as f32 / inside as f32;
        assert!(
            f > 0.25 && f < 0.4,
            "sunlit fraction of the floor inside: {f}"
        );
        // No direct sun on the roof's underside or the walls' inner faces (the side walls
        // are parallel to the sun: cos < 1e-3 counts as unlit).
        for k in 0..200 {
            let (u, v) = (
                (k % 20) as f32 / 20.0 + 0.025,
                (k / 20) as f32 / 10.0 + 0.05,
            );
            let faces = [
                (
                    Vec3::new(-6.0 + 12.0 * u, 3.0, -4.0 + 14.0 * v),
                    Vec3::NEG_Y,
                ),
                (Vec3::new(-6.0 + 12.0 * u, 3.0 * v, -4.0), Vec3::Z),
                (Vec3::new(-6.0, 3.0 * v, -4.0 + 8.0 * u), Vec3::X),
                (Vec3::new(6.0, 3.0 * v, -4.0 + 8.0 * u), Vec3::NEG_X),
            ];
            for (p, n) in faces {
                assert!(!lit(p, n, &mut c), "sunlit at {p}");
            }
        }
    }

    #[test]
    fn the_bright_windows_are_mostly_hidden_from_the_floor_the_camera_sees() {
        use crate::sampling::rng::SampleRng;
        let s = build(0.25, 0).unwrap();
        let env = &s.envmap;
        // Most of the map's power is in the high window, above the roof's edge.
        let high = procedural::direction(190.0, 45.0);
        let t = crate::sampling::octahedral::texel_of(high, env.resolution());
        assert!(env.texels()[(t.y * env.resolution() + t.x) as usize][0] >= 29.0);
        // Irradiance at the centre pixel's floor point, with and without occlusion, by
        // sampling the map (unbiased for both).
        let h = centre_hit(&s);
        let o = s.scene.offset_point(h.position, Vec3::Y);
        let mut counters = crate::geometry::TraversalCounters::default();
        let (mut open, mut seen) = (0.0, 0.0);
        for i in 0..4000 {
            let [u, v] = SampleRng::new(3, i, 0).get2(0);
            let (d, pdf) = env.sample(glam::DVec2::new(u as f64, v as f64)).unwrap();
            if d.y <= 0.0 {
                continue;
            }
            let e = crate::lights::envmap::luminance(env.eval(d).to_array()) * d.y as f64 / pdf;
            open += e;
            if !s.scene.occluded1(o, d, f32::INFINITY, &mut counters) {
                seen += e;
            }
        }
        let fraction = seen / open;
        assert!(
            fraction > 0.005 && fraction < 0.2,
            "visible fraction {fraction}"
        );
    }
}
