//! `garden`: a lawn of thin grass blades with a few tulips.
//!
//! **Purpose.** Hundreds of thousands of thin, randomly placed blades make visibility
//! from the ground nearly random: neighbouring points see very different parts of the
//! sky. This is the hard case for visibility caching (records barely correlate) and a
//! large, cheap-to-build scene for tracing benchmarks.
//!
//! **World** (metres, ground at y = 0):
//! - `ground`: a 16 x 16 m square of soil centred at the origin, normal +y.
//! - `grass`: 100,000 x detail blades, uniformly spread over the 5 x 5 m patch
//!   x, z in [-2.5, 2.5]. Each blade is a tapered strip of 4 triangles (two quads) rooted
//!   at y = 0: height 0.08-0.30 m (more short than tall), width 5-10 mm at the root,
//!   random orientation about +y and a random forward/backward bend of up to half its
//!   height at the tip. One-sided geometry: strips have no thickness.
//! - `tulip<i>_stem` and `tulip<i>_cup` for i in 0..7, within 0.35 m of (0.1, 0, 1.3):
//!   a closed tube stem (4 mm radius, 6 sides, 0.35-0.45 m high, slightly bent, its
//!   bottom ring leaning a few micrometres below the ground) and an
//!   open cup (a surface of revolution 5 cm across and 6 cm deep, closed at the bottom,
//!   open at the top, zero thickness) in red, yellow, pink or white.
//!
//! **Triangles.** 400,000 x detail for the grass, 2 x ceil(16 sqrt(detail))^2 for the
//! ground, 1,820 for the tulips (260 each): 402,332 at detail 1.
//!
//! **Camera.** Looking down at 45 degrees from eye (0, 1.2, 2.2) toward (0, 0, 1), vertical
//! field of view 45 degrees, 256 x 192: the frame is all lawn (x within ~1.5 m, z from
//! -0.7 to 1.7) with the tulips above its centre. Blade placement, shape and the tulips
//! depend on the seed; generation runs in parallel in fixed chunks, so the result does
//! not depend on the thread count.
//!
//! **Environment.** [`super::daylight`] with the sun at azimuth 250°, elevation 35°
//! (low from the camera's left): blades cast long, thin shadows across each other, and
//! every point of the lawn sees a different, fragmented part of the sky.

use std::f32::consts::TAU;

use glam::Vec3;
use rayon::prelude::*;

use super::shapes::{cells, ground, lathe, strip, tube, tube_triangles, uniform, Tri};
use super::{camera, check_detail, setup, Setup};
use crate::bsdf::Material;
use crate::error::Result;
use crate::geometry::Mesh;
use crate::lights::EnvMap;
use crate::sampling::rng::mix64;

/// Side of the square grass patch (m).
pub const PATCH: f32 = 5.0;
/// Blades at detail 1.
pub const BLADES: f32 = 100_000.0;
/// Triangles per blade.
pub const BLADE_TRIANGLES: usize = 4;
/// Number of tulips.
pub const TULIPS: usize = 7;

const BLADES_PER_CHUNK: usize = 2048;
const SALT_GRASS: u64 = 0x0067_7261_7373;
const SALT_TULIP: u64 = 0x0074_756c_6970;

/// The four triangles of blade `i`.
fn blade(seed: u64, i: u64, out: &mut Vec<Tri>) {
    let u = |d: u64| uniform(seed, i, 0, d);
    let base = Vec3::new((u(0) - 0.5) * PATCH, 0.0, (u(1) - 0.5) * PATCH);
    let h = 0.08 + 0.22 * u(2) * u(2);
    let half_width = 0.0025 + 0.0025 * u(3);
    let (s, c) = (TAU * u(4)).sin_cos();
    let side = Vec3::new(c, 0.0, s);
    let facing = Vec3::new(-s, 0.0, c);
    let bend = (2.0 * u(5) - 1.0) * 0.5;
    // Quadratic bend toward `facing`; the height shrinks a little so the blade's length
    // stays near h.
    let at = |t: f32| {
        let lean = bend * t * t;
        base + Vec3::Y * (h * t * (1.0 - 0.5 * lean * lean)) + facing * (h * lean)
    };
    strip(
        out,
        &[at(0.0), at(0.55), at(1.0)],
        &[half_width, 0.7 * half_width, 0.12 * half_width],
        side,
    );
}

/// Stem and cup of tulip `i`.
fn tulip(seed: u64, i: u64, stem: &mut Vec<Tri>, cup: &mut Vec<Tri>) {
    let u = |d: u64| uniform(seed, i, 0, d);
    let (r, a) = (0.35 * u(0).sqrt(), TAU * u(1));
    let base = Vec3::new(0.1 + r * a.cos(), 0.0, 1.3 + r * a.sin());
    let height = 0.35 + 0.1 * u(2);
    let lean = Vec3::new(u(3) - 0.5, 0.0, u(4) - 0.5) * 0.15;
    let points: Vec<Vec3> = (0..=12)
        .map(|k| {
            let t = k as f32 / 12.0;
            base + Vec3::Y * (height * t) + lean * (height * t * t)
        })
        .collect();
    tube(stem, &points, 0.004, 6, true);
    let top = points[12];
    let axis = (top - points[11]).normalize();
    let profile = [
        (0.0, -0.005),
        (0.012, 0.0),
        (0.022, 0.012),
        (0.026, 0.03),
        (0.025, 0.045),
        (0.02, 0.06),
    ];
    lathe(cup, top, axis, &profile, 12);
}

/// Builds the setup (see the module docs).
pub fn build(detail: f32, seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    let mut mesh = Mesh::new();

    let mut t = Vec::new();
    let size = 16.0;
    ground(&mut t, Vec3::ZERO, size, cells(size, 1.0 / detail.sqrt()));
    mesh.add_triangles(
        t,
        Material::lambert([0.22, 0.16, 0.1])?,
        Some("ground".into()),
    )?;

    let blades = ((BLADES * detail).round() as usize).max(1);
    let grass_seed = mix64(seed ^ SALT_GRASS);
    let mut grass = vec![[Vec3::ZERO; 3]; blades * BLADE_TRIANGLES];
    grass
        .par_chunks_mut(BLADES_PER_CHUNK * BLADE_TRIANGLES)
        .enumerate()
        .for_each(|(c, chunk)| {
            let mut buf = Vec::with_capacity(BLADE_TRIANGLES);
            for (k, dst) in chunk.chunks_mut(BLADE_TRIANGLES).enumerate() {
                buf.clear();
                blade(grass_seed, (c * BLADES_PER_CHUNK + k) as u64, &mut buf);
                dst.copy_from_slice(&buf);
            }
        });
    mesh.add_triangles(
        grass,
        Material::lambert([0.1, 0.35, 0.06])?,
        Some("grass".into()),
    )?;

    let stem_material = Material::lambert([0.15, 0.4, 0.1])?;
    let petals = [
        [0.7, 0.05, 0.08],
        [0.8, 0.65, 0.05],
        [0.75, 0.3, 0.45],
        [0.8, 0.8, 0.75],
    ];
    let tulip_seed = mix64(seed ^ SALT_TULIP);
    for i in 0..TULIPS {
        let (mut stem, mut cup) = (Vec::new(), Vec::new());
        tulip(tulip_seed, i as u64, &mut stem, &mut cup);
        let kd = petals[i % petals.len()];
        mesh.add_triangles(stem, stem_material, Some(format!("tulip{i}_stem")))?;
        mesh.add_triangles(
            cup,
            Material::phong(kd, [0.1; 3], 20.0)?,
            Some(format!("tulip{i}_cup")),
        )?;
    }

    let cam = camera([0.0, 1.2, 2.2], [0.0, 0.0, 1.0], 45.0)?;
    Ok(setup("garden", mesh, cam, envmap()?))
}

/// Triangles of one tulip (stem and cup).
pub const TULIP_TRIANGLES: usize = tube_triangles(13, 6, true) + 12 * 9;

/// The default environment: sky and a low sun (see the module docs).
pub fn envmap() -> Result<EnvMap> {
    super::daylight(250.0, 35.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::testing::*;

    #[test]
    fn loads_with_documented_size() {
        let d = 0.05;
        let s = build(d, 0).unwrap();
        let expect = 5000 * BLADE_TRIANGLES + 2 * 4 * 4 + TULIPS * TULIP_TRIANGLES;
        check_basic(&s, "garden", expect..=expect);
        let grass = s.scene.mesh().objects.iter().find(|o| o.name == "grass");
        assert_eq!(
            grass.unwrap().num_triangles as usize,
            5000 * BLADE_TRIANGLES
        );
        let b = s.scene.bounds();
        // Stem rings lean a little below the ground.
        assert!(b.min.y > -1e-3 && b.max.x == 8.0, "{b:?}");
        assert!(b.max.y < 0.55, "{b:?}");
        check_seeds(build, d, true);
        check_scaling(build, d);
    }

    #[test]
    fn blades_stay_in_the_patch_and_are_not_degenerate() {
        let mut t = Vec::new();
        for i in 0..2000 {
            blade(5, i, &mut t);
        }
        assert_eq!(t.len(), 2000 * BLADE_TRIANGLES);
        for tri in &t {
            assert!(crate::math::triangle_cross(tri).length() > 0.0);
            for v in tri {
                assert!(v.x.abs() <= 2.7 && v.z.abs() <= 2.7 && (0.0..0.31).contains(&v.y));
            }
        }
    }

    #[test]
    fn the_camera_sees_grass_everywhere() {
        let s = build(0.05, 0).unwrap();
        let c = &s.camera;
        let mut counters = crate::geometry::TraversalCounters::default();
        for (x, y) in [(0.0, 0.0), (255.9, 0.0), (0.0, 191.9), (255.9, 191.9)] {
            let d = c.direction(x, y);
            let h = s
                .scene
                .intersect1(c.eye, d, f32::INFINITY, &mut counters)
                .unwrap();
            let p = h.position;
            assert!(p.x.abs() < PATCH / 2.0 && p.z.abs() < PATCH / 2.0, "{p}");
        }
    }
}
