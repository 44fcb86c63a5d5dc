//! The direction pattern of visibility records (CAM08 §5.5): one sample direction per texel
//! of a `2^M x 2^M` equal-area octahedral grid, stratified (jittered) inside its texel and
//! then relaxed by Lloyd iterations to improve its blue-noise character.
//!
//! ## Where the relaxation runs: on the sphere
//!
//! The directions are what matters (records sample visibility over the sphere), so Lloyd's
//! algorithm runs on the sphere, with chord distances in 3D:
//! - the map is equal-area but not conformal: near the diagonals (the equator) and the
//!   corners a texel is a sheared, stretched quadrilateral on the sphere, so a pattern that
//!   is blue noise in the square's coordinates is not blue noise over directions;
//! - in 3D the map's folds disappear: a texel on an edge of the square simply has its
//!   neighbours across the fold (found with [`wrap_texel`]), and no torus-like unfolding of
//!   distances is needed;
//! - because the map is equal-area, a regular grid of `K x K` points inside every texel is a
//!   uniform, equally weighted discretisation of the sphere, so the centroid of a spherical
//!   Voronoi cell is the normalised mean of the fine points it owns.
//!
//! One iteration (a Jacobi update, so it is independent of the thread count):
//! 1. every fine point is assigned to the nearest generator among the generators of its own
//!    texel and the 8 texels around it;
//! 2. each generator moves to the centroid of its fine points, the move is taken back to the
//!    square through the local inverse Jacobian of the map, and the result is clamped inside
//!    the generator's own texel (with a margin of [`TEXEL_MARGIN`] texels), so bit `i` of a
//!    record always belongs to texel `i`.
//!
//! The constraint keeps the strata: the relaxation only evens out the jitter's clumping (the
//! minimum nearest-neighbour distance of the jittered pattern is close to zero; see the
//! tests for the figures).
//!
//! Patterns are deterministic per `(M, seed, iterations)` and listed in Morton order
//! ([`morton_encode`], x on the even bits): entry `i` is the direction of bit `i` of a
//! record (CAM08 eq. 10).

use std::sync::OnceLock;

use glam::{DVec3, UVec2, Vec2, Vec3};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::sampling::octahedral::{
    morton_decode, morton_encode, square_to_sphere, texel_of, wrap_texel,
};
use crate::sampling::rng::{hash4, to_unit_f32};
use crate::stop::Stop;

/// Smallest record resolution exponent `M` (a 2 x 2 grid).
pub const MIN_LOG2_RESOLUTION: u32 = 1;
/// Largest record resolution exponent `M` (a 128 x 128 grid, 16384 directions).
pub const MAX_LOG2_RESOLUTION: u32 = 7;
/// Default record resolution exponent: 32 x 32 (CAM08's records).
pub const DEFAULT_LOG2_RESOLUTION: u32 = 5;
/// Default number of Lloyd iterations (CAM08 §5.5 uses 10–30).
pub const DEFAULT_LLOYD_ITERATIONS: u32 = 20;
/// Seed of the default patterns returned by [`default_pattern`].
pub const DEFAULT_PATTERN_SEED: u64 = 0;
/// Fine points per texel side used to estimate the Voronoi centroids (`K x K` per texel).
pub const CENTROID_SUBSAMPLES: u32 = 8;
/// Distance, in texel widths, that a relaxed point keeps from its texel's border.
pub const TEXEL_MARGIN: f32 = 0.02;

/// Checks that `m` is a supported resolution exponent (`1..=7`).
pub fn check_log2_resolution(m: u32) -> Result<()> {
    if (MIN_LOG2_RESOLUTION..=MAX_LOG2_RESOLUTION).contains(&m) {
        Ok(())
    } else {
        Err(Error::invalid(
            "m",
            format!(
                "record resolution exponent must be in {MIN_LOG2_RESOLUTION}..={MAX_LOG2_RESOLUTION} \
                 (grids 2x2 to 128x128), got {m}"
            ),
        ))
    }
}

/// The record direction pattern for a `2^m x 2^m` grid: `4^m` unit directions in Morton
/// order, entry `i` inside texel `morton_decode(i)`. Jittered by
/// `hash4(seed, texel, 0, 0..2)`, then relaxed by `iterations` Lloyd iterations on the
/// sphere (module docs). `iterations = 0` gives the plain stratified pattern. Bit-identical
/// for a given `(m, seed, iterations)` on any thread count. Fails for `m` outside `1..=7`.
pub fn record_pattern(m: u32, seed: u64, iterations: u32) -> Result<Vec<Vec3>> {
    Ok(relaxed_square(m, seed, iterations)?
        .into_iter()
        .map(square_to_sphere)
        .collect())
}

/// The points of [`record_pattern`] in the octahedral square, before they are mapped to
/// the sphere.
fn relaxed_square(m: u32, seed: u64, iterations: u32) -> Result<Vec<Vec2>> {
    check_log2_resolution(m)?;
    let res = 1u32 << m;
    let n = (res * res) as usize;
    // Positions in the square, per texel (Morton index).
    let mut square: Vec<Vec2> = (0..n)
        .map(|i| {
            let t = morton_decode(i as u32);
            let j = Vec2::new(
                to_unit_f32(hash4(seed, i as u64, 0, 0)),
                to_unit_f32(hash4(seed, i as u64, 0, 1)),
            );
            clamp_into_texel(t, res, (t.as_vec2() + j) / res as f32)
        })
        .collect();
    if iterations > 0 {
        let k = CENTROID_SUBSAMPLES;
        // Fine points of every texel, texel-major in Morton order.
        let fine: Vec<Vec3> = (0..n)
            .into_par_iter()
            .flat_map_iter(|i| {
                let t = morton_decode(i as u32).as_vec2();
                (0..k * k).map(move |s| {
                    let o = Vec2::new((s % k) as f32 + 0.5, (s / k) as f32 + 0.5) / k as f32;
                    square_to_sphere((t + o) / res as f32)
                })
            })
            .collect();
        let neighbours: Vec<[u32; 9]> = (0..n).map(|i| neighbour_texels(i as u32, res)).collect();
        let per = (k * k) as usize;
        let mut owner = vec![0u32; fine.len()];
        // An iteration at 128² is tens of milliseconds: a first use polls between them.
        let stop = Stop::current();
        for _ in 0..iterations {
            stop.check("relaxing the records' direction pattern")?;
            let dirs: Vec<Vec3> = square.iter().map(|&p| square_to_sphere(p)).collect();
            // 1. Nearest generator of every fine point.
            owner
                .par_chunks_mut(per)
                .zip(fine.par_chunks(per))
                .enumerate()
                .for_each(|(i, (own, pts))| {
                    for (o, p) in own.iter_mut().zip(pts) {
                        let mut best = (f32::INFINITY, i as u32);
                        for &g in &neighbours[i] {
                            if g == u32::MAX {
                                continue;
                            }
                            let d = dirs[g as usize].distance_squared(*p);
                            if d < best.0 {
                                best = (d, g);
                            }
                        }
                        *o = best.1;
                    }
                });
            // 2. Move every generator to its centroid, inside its own texel.
            square = (0..n)
                .into_par_iter()
                .map(|i| {
                    let mut sum = DVec3::ZERO;
                    for &t in &neighbours[i] {
                        if t == u32::MAX {
                            continue;
                        }
                        let range = t as usize * per..(t as usize + 1) * per;
                        for (o, p) in owner[range.clone()].iter().zip(&fine[range]) {
                            if *o == i as u32 {
                                sum += p.as_dvec3();
                            }
                        }
                    }
                    let texel = morton_decode(i as u32);
                    if sum.length_squared() == 0.0 {
                        return square[i];
                    }
                    let target = sum.normalize().as_vec3();
                    let p = move_towards(square[i], target, res);
                    clamp_into_texel(texel, res, p)
                })
                .collect();
        }
    }
    Ok(square)
}

/// The default pattern for resolution exponent `m` ([`DEFAULT_PATTERN_SEED`],
/// [`DEFAULT_LLOYD_ITERATIONS`]), made once per `m` and shared. Fails for `m` outside
/// `1..=7`, and with [`Error::Interrupted`] when the current [`Stop`] is set while a
/// pattern that is not baked is relaxed on its first use (then the next use relaxes it).
///
/// The resolutions the presets and the coherence check use ([`BAKED_LOG2_RESOLUTIONS`])
/// are read from points relaxed ahead of time (`default_patterns.bin`): the relaxation of
/// a 64² pattern takes about 0.1 s on two cores, which a user's first control-variate
/// render would otherwise pay, longer than a whole 10-spp render of a small view. The
/// baked points are the relaxation's to within rounding (`sin`/`cos` may differ in the
/// last bit between machines; a test checks 1e-6) and are the same on every machine.
pub fn default_pattern(m: u32) -> Result<&'static [Vec3]> {
    check_log2_resolution(m)?;
    static PATTERNS: [OnceLock<Vec<Vec3>>; MAX_LOG2_RESOLUTION as usize] =
        [const { OnceLock::new() }; MAX_LOG2_RESOLUTION as usize];
    let slot = &PATTERNS[(m - 1) as usize];
    if let Some(pattern) = slot.get() {
        return Ok(pattern);
    }
    // Made outside the lock, so that a stopped relaxation ([`Stop`]) fails this call and
    // leaves the slot empty; callers racing here make the same points, and one is kept.
    let square = match baked_square(m) {
        Some(square) => square,
        None => relaxed_square(m, DEFAULT_PATTERN_SEED, DEFAULT_LLOYD_ITERATIONS)?,
    };
    let pattern = square.into_iter().map(square_to_sphere).collect();
    Ok(slot.get_or_init(|| pattern))
}

/// Resolution exponents whose default pattern is baked into the library (the coherence
/// check's 16², the `low`/`medium`/`high` presets' 32² and `auto`'s 64²).
pub const BAKED_LOG2_RESOLUTIONS: std::ops::RangeInclusive<u32> = 4..=6;

/// The default patterns of [`BAKED_LOG2_RESOLUTIONS`] in the square, one after another
/// in increasing `m`, each point two little-endian `f32`.
static BAKED_SQUARES: &[u8] = include_bytes!("default_patterns.bin");

/// The baked square points of the default pattern at `m`, if it is baked.
fn baked_square(m: u32) -> Option<Vec<Vec2>> {
    if !BAKED_LOG2_RESOLUTIONS.contains(&m) {
        return None;
    }
    let skip: usize = (*BAKED_LOG2_RESOLUTIONS.start()..m)
        .map(|k| 8 << (2 * k))
        .sum();
    let bytes = BAKED_SQUARES.get(skip..skip + (8 << (2 * m)))?;
    let f = |b: &[u8]| f32::from_le_bytes(b.try_into().expect("four bytes"));
    Some(
        bytes
            .chunks_exact(8)
            .map(|p| Vec2::new(f(&p[..4]), f(&p[4..])))
            .collect(),
    )
}

/// The Morton indices of texel `i` and its 8 grid neighbours (across the square's folds),
/// each once; unused slots are `u32::MAX`.
fn neighbour_texels(i: u32, res: u32) -> [u32; 9] {
    let t = morton_decode(i);
    let mut out = [u32::MAX; 9];
    let mut len = 0;
    for dy in -1i64..=1 {
        for dx in -1i64..=1 {
            let w = wrap_texel(t.x as i64 + dx, t.y as i64 + dy, res);
            let code = morton_encode(w.x, w.y);
            if !out[..len].contains(&code) {
                out[len] = code;
                len += 1;
            }
        }
    }
    out
}

/// Moves the square position `p` so that its direction approaches `target`: the 3D step is
/// taken back to the square through the least-squares inverse of the map's Jacobian at `p`
/// (one-sided differences a quarter texel wide, towards the square's inside).
fn move_towards(p: Vec2, target: Vec3, res: u32) -> Vec2 {
    let h = 0.25 / res as f32;
    let d = square_to_sphere(p);
    let step = |axis: Vec2| {
        let q = p + axis * h;
        let (q, sign) = if q.x <= 1.0 && q.y <= 1.0 {
            (q, 1.0)
        } else {
            (p - axis * h, -1.0)
        };
        (square_to_sphere(q) - d) * (sign / h)
    };
    let (ju, jv) = (step(Vec2::X).as_dvec3(), step(Vec2::Y).as_dvec3());
    let delta = (target - d).as_dvec3();
    // Normal equations of the 3x2 system [ju jv] x = delta.
    let (a, b, c) = (ju.dot(ju), ju.dot(jv), jv.dot(jv));
    let det = a * c - b * b;
    if det.abs() < 1e-12 * a.max(c).max(1e-30) {
        return p;
    }
    let (ru, rv) = (ju.dot(delta), jv.dot(delta));
    let x = (c * ru - b * rv) / det;
    let y = (a * rv - b * ru) / det;
    p + Vec2::new(x as f32, y as f32)
}

/// Clamps square position `p` inside texel `t` of a `res x res` grid, [`TEXEL_MARGIN`]
/// texels away from its border, and pulls it towards the texel's centre until the direction
/// it maps to lies in `t` (guards against rounding in the map).
fn clamp_into_texel(t: UVec2, res: u32, p: Vec2) -> Vec2 {
    let lo = (t.as_vec2() + TEXEL_MARGIN) / res as f32;
    let hi = (t.as_vec2() + (1.0 - TEXEL_MARGIN)) / res as f32;
    let centre = (t.as_vec2() + 0.5) / res as f32;
    let mut q = p.clamp(lo, hi);
    for _ in 0..32 {
        if texel_of(square_to_sphere(q), res) == t {
            return q;
        }
        q = centre + (q - centre) * 0.5;
    }
    centre
}

/// Blue-noise figures of a set of unit directions: the minimum and mean chord distance
/// from each direction to its nearest other one, both divided by the spacing of a regular
/// pattern with the same count (`sqrt(4π / n)`). Brute force, `O(n²)`; for tests and
/// reports.
pub fn nearest_neighbour_stats(dirs: &[Vec3]) -> (f64, f64) {
    let n = dirs.len();
    if n < 2 {
        return (0.0, 0.0);
    }
    let nn: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut best = f64::INFINITY;
            for (j, d) in dirs.iter().enumerate() {
                if j != i {
                    best = best.min(dirs[i].as_dvec3().distance(d.as_dvec3()));
                }
            }
            best
        })
        .collect();
    let spacing = (4.0 * std::f64::consts::PI / n as f64).sqrt();
    let min = nn.iter().cloned().fold(f64::INFINITY, f64::min);
    let mean = nn.iter().sum::<f64>() / n as f64;
    (min / spacing, mean / spacing)
}

#[cfg(test)]
mod tests {
    /// The baked default patterns are the relaxation's (to rounding), and the file holds
    /// exactly them.
    #[test]
    fn baked_default_patterns_are_the_relaxed_ones() {
        let expected: usize = BAKED_LOG2_RESOLUTIONS.map(|m| 8 << (2 * m)).sum();
        assert_eq!(BAKED_SQUARES.len(), expected);
        for m in BAKED_LOG2_RESOLUTIONS {
            let baked = baked_square(m).unwrap();
            let relaxed =
                relaxed_square(m, DEFAULT_PATTERN_SEED, DEFAULT_LLOYD_ITERATIONS).unwrap();
            assert_eq!(baked.len(), relaxed.len());
            let worst = baked
                .iter()
                .zip(&relaxed)
                .map(|(a, b)| (*a - *b).abs().max_element())
                .fold(0.0f32, f32::max);
            assert!(worst <= 1e-6, "m = {m}: baked points differ by {worst}");
            let dirs = default_pattern(m).unwrap();
            for (i, d) in dirs.iter().enumerate() {
                assert_eq!(
                    texel_of(*d, 1 << m),
                    morton_decode(i as u32),
                    "m = {m}, {i}"
                );
            }
        }
        assert!(baked_square(3).is_none() && baked_square(7).is_none());
    }

    /// A relaxation polls the current stop between iterations: set, it fails with
    /// `Interrupted`; the unrelaxed points (no iteration) are made whatever the stop.
    #[test]
    fn a_set_stop_interrupts_a_relaxation() {
        let stop = crate::stop::Stop::new();
        stop.set();
        let e = stop.scope(|| relaxed_square(3, 1, 2)).unwrap_err();
        assert!(matches!(e, Error::Interrupted { .. }), "{e}");
        assert_eq!(stop.scope(|| relaxed_square(3, 1, 0)).unwrap().len(), 64);
        assert_eq!(relaxed_square(3, 1, 2).unwrap().len(), 64);
    }

    /// Writes `default_patterns.bin` (run after a change to the relaxation:
    /// `cargo test --release -- --ignored bake_default_patterns`).
    #[test]
    #[ignore]
    fn bake_default_patterns() {
        let mut bytes = Vec::new();
        for m in BAKED_LOG2_RESOLUTIONS {
            for p in relaxed_square(m, DEFAULT_PATTERN_SEED, DEFAULT_LLOYD_ITERATIONS).unwrap() {
                bytes.extend(p.x.to_le_bytes());
                bytes.extend(p.y.to_le_bytes());
            }
        }
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/rust/src/sampling/default_patterns.bin"
        );
        std::fs::write(path, bytes).unwrap();
    }

    use super::*;
    use crate::sampling::octahedral::sphere_to_square;

    #[test]
    fn every_direction_is_unit_and_in_its_own_texel_at_every_resolution() {
        for m in MIN_LOG2_RESOLUTION..=MAX_LOG2_RESOLUTION {
            let res = 1u32 << m;
            let dirs = default_pattern(m).unwrap();
            assert_eq!(dirs.len(), (res * res) as usize);
            for (i, d) in dirs.iter().enumerate() {
                assert!((d.length() - 1.0).abs() < 1e-5, "m {m}, {i}: {d}");
                assert_eq!(
                    texel_of(*d, res),
                    morton_decode(i as u32),
                    "m {m}, {i}: {d}"
                );
                // Also away from the texel's border in the square (by about the margin).
                let p = sphere_to_square(*d) * res as f32 - morton_decode(i as u32).as_vec2();
                let margin = TEXEL_MARGIN * 0.5;
                assert!(
                    p.min_element() > margin && p.max_element() < 1.0 - margin,
                    "{p}"
                );
            }
        }
    }

    #[test]
    fn deterministic_and_seed_dependent() {
        let a = record_pattern(4, 3, 5).unwrap();
        let b = record_pattern(4, 3, 5).unwrap();
        assert_eq!(a, b);
        let c = record_pattern(4, 4, 5).unwrap();
        assert_ne!(a, c);
        let single = crate::parallel::with_threads(Some(1), || record_pattern(4, 3, 5))
            .unwrap()
            .unwrap();
        assert_eq!(a, single, "same pattern on one thread");
        assert_eq!(
            default_pattern(3).unwrap(),
            &record_pattern(3, 0, 20).unwrap()[..]
        );
    }

    #[test]
    fn out_of_range_resolutions_are_errors() {
        for m in [0, 8, 100] {
            let e = record_pattern(m, 0, 1).unwrap_err().to_string();
            assert!(e.starts_with("m:"), "{e}");
            assert!(default_pattern(m).is_err());
        }
    }

    /// Minimum / mean nearest-neighbour chord distance in units of `sqrt(4π / n)`, seed 0:
    ///
    /// | pattern                       | 8 x 8       | 32 x 32     |
    /// |-------------------------------|-------------|-------------|
    /// | jittered (0 iterations)       | 0.11 / 0.60 | 0.10 / 0.63 |
    /// | relaxed (20 iterations)       | 0.72 / 0.94 | 0.68 / 0.94 |
    /// | texel centres (no jitter)     | 0.88 / 0.92 | 0.83 / 0.94 |
    ///
    /// Relaxation brings the jittered pattern to the mean spacing of the regular grid of
    /// texel centres while staying irregular (no aliasing with straight edges); its minimum
    /// stays below the grid's because every point is confined to its own texel.
    #[test]
    fn relaxation_improves_the_nearest_neighbour_distances() {
        for m in [3u32, 5] {
            let res = 1u32 << m;
            let jittered = nearest_neighbour_stats(&record_pattern(m, 0, 0).unwrap());
            let relaxed = nearest_neighbour_stats(default_pattern(m).unwrap());
            let centres: Vec<Vec3> = (0..res * res)
                .map(|i| crate::sampling::octahedral::texel_center(morton_decode(i), res))
                .collect();
            let centres = nearest_neighbour_stats(&centres);
            println!(
                "m {m}: min/mean jittered {jittered:?}, relaxed {relaxed:?}, centres {centres:?}"
            );
            assert!(relaxed.0 > 5.0 * jittered.0, "{jittered:?} -> {relaxed:?}");
            assert!(relaxed.1 > 1.3 * jittered.1, "{jittered:?} -> {relaxed:?}");
        }
    }

    #[test]
    fn more_iterations_keep_improving_then_settle() {
        let s = |it| nearest_neighbour_stats(&record_pattern(5, 1, it).unwrap()).1;
        let (a, b, c) = (s(0), s(5), s(20));
        println!("mean nn at 0 / 5 / 20 iterations: {a} {b} {c}");
        assert!(a < b && b <= c * 1.01, "{a} {b} {c}");
    }
}
