//! Visibility correlation measurements (Clarberg & Akenine-Möller 2008, "CAM08", §4.1,
//! Figs. 3–4).
//!
//! ## What is measured
//! `V_i(ω) = V(x_i, ω)` is the binary visibility of the whole sphere at surface point `x_i`
//! (CAM08 eq. 7; the lower hemisphere is occluded by definition), sampled at the `N = 4^M`
//! directions of [`default_pattern`] — the same maps the cache records hold
//! ([`Record::trace`]). For two points the Pearson correlation of the two maps over the `N`
//! directions, with `a = popcount(V_i)`, `b = popcount(V_j)`, `c = popcount(V_i & V_j)`, is
//!
//! `ρ_ij = (N c − a b) / sqrt(a (N − a) · b (N − b))`,
//!
//! in `[−1, 1]`: 1 for identical maps, −1 for complementary ones. It is undefined when a map
//! is constant (all occluded or all visible: zero variance); such pairs are counted, never
//! averaged ([`pearson_from_counts`] returns `None`).
//!
//! CAM08 §4.1 averages ρ over pairs binned by distance `d = |x_i − x_j|` (world units) and
//! normal difference `θ = acos(n_i · n_j)` (degrees): `ρ̄(d, θ)` with a standard deviation
//! per bin ([`correlation_bins`]). Fig. 4's top row is the average ρ from each point to the
//! points within `(d_max, θ_max)` ([`local_correlation`]).
//!
//! ## Pairs
//! The paper draws "a large number of randomly chosen pairs" from ~700k points; uniformly
//! random pairs almost never land in the small-`d` bins that matter most, so
//! [`sample_pairs`] draws each point's partners in two ways, both deterministic:
//! - its `neighbours` nearest points (kd-tree; ties broken by the tree), which fill the
//!   bins below a few point spacings;
//! - `far` partners found as the point nearest to `x_i + r u` within `r / 2` of it, with `u`
//!   uniform on the unit circle of `x_i`'s tangent plane and `r` log-uniform in
//!   `[far_min, far_max]`, drawn from `(seed, i, draw)`: distances spread over every scale
//!   up to the scene's size. Along the tangent plane the query stays near surfaces that
//!   continue `x_i`'s; a query far above a large plane would make the kd-tree visit every
//!   leaf of the plane within that height (all its points are about equally far), which the
//!   `r / 2` bound also cuts off. A draw with no point within `r / 2` yields no pair.
//!
//! Pairs are ordered draws `(i, j)`: mutual neighbours appear twice and a far draw may
//! repeat a pair. A bin's mean is therefore the mean over the drawn pairs, which weights
//! pairs by how often the scheme draws them rather than uniformly over all pairs in the bin
//! (for small point sets [`Pairs::All`] takes every unordered pair once instead).
//!
//! ## Determinism
//! Maps are pure functions of their point; pairs of `(seed, i, draw)`; bins are accumulated
//! in fixed chunks of pairs (Welford within a chunk, Chan et al.'s merge across chunks in
//! chunk order), so every result is bit-identical for any thread count.

use std::num::NonZeroUsize;

use glam::Vec3;
use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::geometry::Scene;
use crate::parallel::with_threads;
use crate::sampling::pattern::default_pattern;
use crate::sampling::rng::{hash4, to_unit_f64};
use crate::visibility::record::{bit_words, Record};

pub use crate::moments::Moments;

/// Points traced per block between two progress reports of [`VisibilityMaps::trace`].
pub const TRACE_BLOCK: usize = 1024;

/// Pairs per accumulation chunk of [`correlation_bins`] (fixed, so results do not depend on
/// the thread count).
const PAIR_CHUNK: usize = 1 << 15;

/// Rows `i` per chunk when [`correlation_bins`] runs over all pairs.
const ROW_CHUNK: usize = 64;

type Tree = ImmutableKdTree<f32, u32, 3, 32>;

/// CAM08 §4.1's Pearson correlation of two binary maps of `n` directions from popcounts:
/// `a`, `b` set bits in each map, `c` set in both (so `c <= min(a, b)` and `a + b − c <= n`).
///
/// `None` when either map is constant (`a` or `b` is 0 or `n`): ρ is undefined there.
/// Otherwise `(n c − a b) / sqrt(a (n − a) b (n − b))` in `[−1, 1]`; the numerator is exact
/// in integers and the denominator's product exact in `f64` up to `n = 2^26`.
pub fn pearson_from_counts(n: u64, a: u64, b: u64, c: u64) -> Option<f64> {
    if a == 0 || a >= n || b == 0 || b >= n {
        return None;
    }
    debug_assert!(c <= a.min(b) && a + b - c <= n);
    let num = n as i128 * c as i128 - a as i128 * b as i128;
    let den = ((a * (n - a)) as f64 * (b * (n - b)) as f64).sqrt();
    Some((num as f64 / den).clamp(-1.0, 1.0))
}

/// `popcount(a & b)` over two equally long word slices.
#[inline]
fn and_popcount(a: &[u64], b: &[u64]) -> u32 {
    a.iter().zip(b).map(|(x, y)| (x & y).count_ones()).sum()
}

/// Checks `points` and `normals` (same non-zero length, finite points, finite non-zero
/// normals) and returns the unit normals.
fn check_points(points: &[Vec3], normals: &[Vec3]) -> Result<Vec<Vec3>> {
    if points.is_empty() {
        return Err(Error::invalid("points", "must hold at least one point"));
    }
    if points.len() > u32::MAX as usize {
        return Err(Error::invalid("points", "more than 2^32 - 1 points"));
    }
    if normals.len() != points.len() {
        return Err(Error::invalid(
            "normals",
            format!("has {} rows but points has {}", normals.len(), points.len()),
        ));
    }
    if let Some(i) = points.iter().position(|p| !p.is_finite()) {
        return Err(Error::invalid(
            "points",
            format!("row {i} is not finite: {}", points[i]),
        ));
    }
    normals
        .iter()
        .enumerate()
        .map(|(i, n)| {
            let u = n.normalize_or_zero();
            if u == Vec3::ZERO || !u.is_finite() {
                Err(Error::invalid(
                    "normals",
                    format!("row {i} is not a finite non-zero vector: {n}"),
                ))
            } else {
                Ok(u)
            }
        })
        .collect()
}

/// Visibility maps of many surface points (module docs): `4^M` bits each in Morton order
/// (the layout of [`crate::visibility::record`]), with each map's popcount, point and unit
/// normal.
///
/// Invariant: `words.len() == len() * bit_words(m)`, bits beyond `4^M` in a sub-word map are
/// zero, `popcounts[i]` is map `i`'s popcount, and `points`, `normals` have `len()` rows.
#[derive(Clone, Debug, PartialEq)]
pub struct VisibilityMaps {
    m: u32,
    words: Vec<u64>,
    popcounts: Vec<u32>,
    points: Vec<Vec3>,
    normals: Vec<Vec3>,
}

impl VisibilityMaps {
    /// Traces the map of every point with [`Record::trace`] over [`default_pattern`]`(m)`
    /// (`m` in `1..=7`), in parallel on `threads` workers, in blocks of [`TRACE_BLOCK`]
    /// points; `progress(done, total)` is called after each block and stops the trace
    /// early (an error naming `progress`) when it returns `false`.
    ///
    /// Fails on empty or mismatched `points`/`normals`, non-finite points, zero or
    /// non-finite normals, `m` out of range or a bad `threads`.
    pub fn trace(
        scene: &Scene,
        points: &[Vec3],
        normals: &[Vec3],
        m: u32,
        threads: Option<usize>,
        progress: &mut dyn FnMut(usize, usize) -> bool,
    ) -> Result<Self> {
        let pattern = default_pattern(m)?;
        let normals = check_points(points, normals)?;
        let nw = bit_words(m);
        let mut words = crate::alloc::try_with_capacity(points.len().saturating_mul(nw), "points")?;
        for start in (0..points.len()).step_by(TRACE_BLOCK) {
            let end = (start + TRACE_BLOCK).min(points.len());
            let block: Vec<Vec<u64>> = with_threads(threads, || {
                (start..end)
                    .into_par_iter()
                    .with_min_len(8)
                    .map(|i| {
                        let (rec, _) = Record::trace(scene, points[i], normals[i], pattern, 0)?;
                        Ok(rec.bits.view().bit_words().to_vec())
                    })
                    .collect::<Result<Vec<_>>>()
            })??;
            words.extend(block.into_iter().flatten());
            if !progress(end, points.len()) {
                return Err(Error::invalid("progress", "trace stopped by the callback"));
            }
        }
        Self::from_bit_words(m, words, points.to_vec(), normals)
    }

    /// Maps from their bit words (`bit_words(m)` per map, Morton order, concatenated),
    /// points and normals (normalised here). Fails on a wrong word count, set bits beyond
    /// `4^m`, or the point checks of [`VisibilityMaps::trace`].
    pub fn from_bit_words(
        m: u32,
        words: Vec<u64>,
        points: Vec<Vec3>,
        normals: Vec<Vec3>,
    ) -> Result<Self> {
        crate::sampling::pattern::check_log2_resolution(m)?;
        let normals = check_points(&points, &normals)?;
        let nw = bit_words(m);
        if words.len() != points.len() * nw {
            return Err(Error::invalid(
                "words",
                format!(
                    "need {} words ({} maps of {nw}), got {}",
                    points.len() * nw,
                    points.len(),
                    words.len()
                ),
            ));
        }
        if m < 3 && words.iter().any(|w| w >> (1u32 << (2 * m)) != 0) {
            return Err(Error::invalid(
                "words",
                format!("bits beyond the {} directions are set", 1u32 << (2 * m)),
            ));
        }
        let popcounts = words
            .chunks_exact(nw)
            .map(|c| c.iter().map(|w| w.count_ones()).sum())
            .collect();
        Ok(Self {
            m,
            words,
            popcounts,
            points,
            normals,
        })
    }

    /// Resolution exponent `M` (maps are `2^M x 2^M`).
    pub fn m(&self) -> u32 {
        self.m
    }

    /// Directions per map, `N = 4^M`.
    pub fn directions(&self) -> u64 {
        1u64 << (2 * self.m)
    }

    /// Number of maps (points).
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Never true: construction requires at least one point.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The bit words of map `i` (Morton order; bit `z` is bit `z % 64` of word `z / 64`).
    pub fn map(&self, i: usize) -> &[u64] {
        let nw = bit_words(self.m);
        &self.words[i * nw..(i + 1) * nw]
    }

    /// Unoccluded directions of map `i`.
    pub fn popcount(&self, i: usize) -> u32 {
        self.popcounts[i]
    }

    /// The surface points, world units.
    pub fn points(&self) -> &[Vec3] {
        &self.points
    }

    /// The unit normals.
    pub fn normals(&self) -> &[Vec3] {
        &self.normals
    }

    /// ρ between maps `i` and `j` ([`pearson_from_counts`]; `None` if either is constant).
    pub fn rho(&self, i: usize, j: usize) -> Option<f64> {
        let c = and_popcount(self.map(i), self.map(j));
        pearson_from_counts(
            self.directions(),
            self.popcounts[i] as u64,
            self.popcounts[j] as u64,
            c as u64,
        )
    }

    /// `(d, θ)` of a pair: distance in world units and angle between the normals in
    /// degrees, both in `f64`.
    pub fn distance_angle(&self, i: usize, j: usize) -> (f64, f64) {
        let d = (self.points[i].as_dvec3() - self.points[j].as_dvec3()).length();
        let c = self.normals[i]
            .as_dvec3()
            .dot(self.normals[j].as_dvec3())
            .clamp(-1.0, 1.0);
        (d, c.acos().to_degrees())
    }

    fn check_pair(&self, k: usize, p: [u32; 2]) -> Result<()> {
        if p[0] as usize >= self.len() || p[1] as usize >= self.len() {
            return Err(Error::invalid(
                "pairs",
                format!(
                    "row {k} ({}, {}) indexes beyond the {} maps",
                    p[0],
                    p[1],
                    self.len()
                ),
            ));
        }
        Ok(())
    }
}

/// How [`sample_pairs`] draws each point's partners (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairSampling {
    /// Nearest points taken as partners of each point (`0..=1024`).
    pub neighbours: usize,
    /// Partners drawn at log-uniform distances in `[far_min, far_max]` (`0..=1024`).
    pub far: usize,
    /// Smallest distance of a far draw, world units (`> 0`).
    pub far_min: f32,
    /// Largest distance of a far draw, world units (`>= far_min`, finite).
    pub far_max: f32,
    /// Seed of the far draws (counter-based: `(seed, point, draw)`).
    pub seed: u64,
}

/// Largest `neighbours` or `far` of [`PairSampling`].
pub const MAX_PARTNERS: usize = 1024;

/// Pairs `(i, j)`, `i != j`, of the maps' points, for every point `i` in order: first its
/// `neighbours` nearest points (nearest first), then its `far` draws in draw order (a draw
/// that finds no point or `i` itself yields no pair). At most `len * (neighbours + far)`
/// pairs. See the module docs.
///
/// Fails with fewer than two points or parameters out of range.
pub fn sample_pairs(
    maps: &VisibilityMaps,
    s: &PairSampling,
    threads: Option<usize>,
) -> Result<Vec<[u32; 2]>> {
    let points = maps.points();
    let normals = maps.normals();
    if points.len() < 2 || points.len() > u32::MAX as usize {
        return Err(Error::invalid(
            "points",
            format!("need 2 to 2^32 - 1 points, got {}", points.len()),
        ));
    }
    if s.neighbours > MAX_PARTNERS {
        return Err(Error::invalid(
            "neighbours",
            format!("must be in 0..={MAX_PARTNERS}, got {}", s.neighbours),
        ));
    }
    if s.far > MAX_PARTNERS {
        return Err(Error::invalid(
            "far",
            format!("must be in 0..={MAX_PARTNERS}, got {}", s.far),
        ));
    }
    if !(s.far_min.is_finite() && s.far_min > 0.0) {
        return Err(Error::invalid(
            "far_min",
            format!("must be finite and > 0, got {}", s.far_min),
        ));
    }
    if !(s.far_max.is_finite() && s.far_max >= s.far_min) {
        return Err(Error::invalid(
            "far_max",
            format!(
                "must be finite and >= far_min = {}, got {}",
                s.far_min, s.far_max
            ),
        ));
    }
    let rows: Vec<[f32; 3]> = points.iter().map(|p| p.to_array()).collect();
    let tree = Tree::new_from_slice(&rows);
    let log_ratio = (s.far_max as f64 / s.far_min as f64).ln();
    let per_point: Vec<Vec<[u32; 2]>> = with_threads(threads, || {
        (0..points.len())
            .into_par_iter()
            .with_min_len(64)
            .map(|i| {
                let mut out = Vec::with_capacity(s.neighbours + s.far);
                if s.neighbours > 0 {
                    // One extra: the point itself (or a duplicate of it) comes back too.
                    let k = NonZeroUsize::new(s.neighbours + 1).expect("k >= 1");
                    let near = tree.nearest_n::<SquaredEuclidean>(&rows[i], k);
                    out.extend(
                        near.iter()
                            .filter(|nb| nb.item as usize != i)
                            .take(s.neighbours)
                            .map(|nb| [i as u32, nb.item]),
                    );
                }
                let p = points[i].as_dvec3();
                let (t1, t2) = normals[i].as_dvec3().any_orthonormal_pair();
                for t in 0..s.far as u64 {
                    let u = |d: u64| to_unit_f64(hash4(s.seed, i as u64, t, d));
                    let r = s.far_min as f64 * (u(0) * log_ratio).exp();
                    let phi = std::f64::consts::TAU * u(1);
                    let q = p + r * (phi.cos() * t1 + phi.sin() * t2);
                    let found = tree.nearest_n_within::<SquaredEuclidean>(
                        &q.as_vec3().to_array(),
                        (0.25 * r * r) as f32,
                        NonZeroUsize::MIN,
                        true,
                    );
                    if let Some(j) = found.first().map(|nb| nb.item) {
                        if j as usize != i {
                            out.push([i as u32, j]);
                        }
                    }
                }
                out
            })
            .collect()
    })?;
    Ok(per_point.into_iter().flatten().collect())
}

/// Which pairs [`correlation_bins`] measures.
#[derive(Clone, Copy, Debug)]
pub enum Pairs<'a> {
    /// Every unordered pair `i < j` once (`len (len − 1) / 2` pairs: small sets only).
    All,
    /// The listed pairs `(i, j)`, each as often as listed.
    List(&'a [[u32; 2]]),
}

/// Bin edges: at least two, finite, strictly increasing; distance edges `>= 0` (world
/// units), angle edges in `[0, 180]` degrees.
fn check_edges(edges: &[f64], name: &str, max: f64) -> Result<()> {
    if edges.len() < 2 {
        return Err(Error::invalid(
            name,
            format!("need at least 2 edges, got {}", edges.len()),
        ));
    }
    if let Some(k) = edges
        .iter()
        .position(|e| !e.is_finite() || *e < 0.0 || *e > max)
    {
        return Err(Error::invalid(
            name,
            format!("edge {k} = {} is not in [0, {max}]", edges[k]),
        ));
    }
    if let Some(k) = edges.windows(2).position(|w| w[1] <= w[0]) {
        return Err(Error::invalid(
            name,
            format!(
                "must be strictly increasing, but edge {} = {} <= edge {k} = {}",
                k + 1,
                edges[k + 1],
                edges[k]
            ),
        ));
    }
    Ok(())
}

/// The bin of `x` among `edges` like `numpy.histogram`: `[e_k, e_{k+1})`, the last bin
/// closed; `None` outside `[e_0, e_last]`.
#[inline]
fn bin_of(edges: &[f64], x: f64) -> Option<usize> {
    let last = *edges.last()?;
    if !(x >= edges[0] && x <= last) {
        return None;
    }
    if x == last {
        return Some(edges.len() - 2);
    }
    Some(edges.partition_point(|e| *e <= x) - 1)
}

/// [`correlation_bins`]'s result: bins row-major by distance then angle (bin
/// `k = d_bin * (theta_edges.len() − 1) + theta_bin`).
#[derive(Clone, Debug, PartialEq)]
pub struct CorrelationBins {
    /// Distance edges, world units.
    pub distance_edges: Vec<f64>,
    /// Angle edges, degrees.
    pub theta_edges: Vec<f64>,
    /// Count, mean and spread of the defined ρ per bin.
    pub moments: Vec<Moments>,
    /// Pairs per bin whose ρ is undefined (a constant map), not in `moments`.
    pub undefined: Vec<u64>,
    /// Pairs whose `d` or `θ` fell outside the edges.
    pub outside: u64,
    /// Pairs measured in all (in bins, undefined and outside).
    pub pairs: u64,
}

impl CorrelationBins {
    fn empty(d: &[f64], t: &[f64]) -> Self {
        let nb = (d.len() - 1) * (t.len() - 1);
        Self {
            distance_edges: d.to_vec(),
            theta_edges: t.to_vec(),
            moments: vec![Moments::default(); nb],
            undefined: vec![0; nb],
            outside: 0,
            pairs: 0,
        }
    }

    #[inline]
    fn add(&mut self, maps: &VisibilityMaps, i: usize, j: usize) {
        self.pairs += 1;
        let (d, theta) = maps.distance_angle(i, j);
        let (Some(bd), Some(bt)) = (
            bin_of(&self.distance_edges, d),
            bin_of(&self.theta_edges, theta),
        ) else {
            self.outside += 1;
            return;
        };
        let k = bd * (self.theta_edges.len() - 1) + bt;
        match maps.rho(i, j) {
            Some(r) => self.moments[k].push(r),
            None => self.undefined[k] += 1,
        }
    }

    fn merge(&mut self, other: &CorrelationBins) {
        for (a, b) in self.moments.iter_mut().zip(&other.moments) {
            a.merge(b);
        }
        for (a, b) in self.undefined.iter_mut().zip(&other.undefined) {
            *a += b;
        }
        self.outside += other.outside;
        self.pairs += other.pairs;
    }
}

/// CAM08 §4.1's `ρ̄(d, θ)`: every pair's ρ binned by distance (`distance_edges`, world
/// units) and normal difference (`theta_edges`, degrees), both like `numpy.histogram`
/// (half-open bins, the last closed). Deterministic for any `threads` (module docs).
///
/// Fails on bad edges (fewer than two, not strictly increasing, negative or non-finite
/// distances, angles outside `[0, 180]`), pair indices beyond the maps, or `Pairs::All`
/// over more than 2^17 maps (~8.6e9 pairs).
pub fn correlation_bins(
    maps: &VisibilityMaps,
    pairs: Pairs<'_>,
    distance_edges: &[f64],
    theta_edges: &[f64],
    threads: Option<usize>,
) -> Result<CorrelationBins> {
    check_edges(distance_edges, "distance_edges", f64::MAX)?;
    check_edges(theta_edges, "theta_edges", 180.0)?;
    let empty = CorrelationBins::empty(distance_edges, theta_edges);
    let chunks: Vec<CorrelationBins> = match pairs {
        Pairs::List(list) => {
            for (k, p) in list.iter().enumerate() {
                maps.check_pair(k, *p)?;
            }
            with_threads(threads, || {
                list.par_chunks(PAIR_CHUNK)
                    .map(|chunk| {
                        let mut acc = empty.clone();
                        for p in chunk {
                            acc.add(maps, p[0] as usize, p[1] as usize);
                        }
                        acc
                    })
                    .collect()
            })?
        }
        Pairs::All => {
            let n = maps.len();
            if n > 1 << 17 {
                return Err(Error::invalid(
                    "pairs",
                    format!("all pairs of {n} maps is too many; pass a list of pairs"),
                ));
            }
            with_threads(threads, || {
                (0..n.div_ceil(ROW_CHUNK))
                    .into_par_iter()
                    .map(|c| {
                        let mut acc = empty.clone();
                        for i in c * ROW_CHUNK..((c + 1) * ROW_CHUNK).min(n) {
                            for j in i + 1..n {
                                acc.add(maps, i, j);
                            }
                        }
                        acc
                    })
                    .collect()
            })?
        }
    };
    let mut out = empty;
    for c in &chunks {
        out.merge(c);
    }
    Ok(out)
}

/// CAM08 Fig. 4 (top row): for every point, the mean ρ to the other points within distance
/// `d_max` (world units, inclusive) whose normals differ by less than `theta_max_deg`, and
/// how many such partners had a defined ρ. NaN where none did. Costs one kd-tree range query
/// and one popcount per partner, so keep `d_max` to a neighbourhood. Deterministic.
///
/// Fails on a non-finite or negative `d_max` or `theta_max_deg` outside `(0, 180]`.
pub fn local_correlation(
    maps: &VisibilityMaps,
    d_max: f64,
    theta_max_deg: f64,
    threads: Option<usize>,
) -> Result<(Vec<f64>, Vec<u32>)> {
    if !(d_max.is_finite() && d_max >= 0.0) {
        return Err(Error::invalid(
            "d_max",
            format!("must be finite and >= 0, got {d_max}"),
        ));
    }
    if !(theta_max_deg > 0.0 && theta_max_deg <= 180.0) {
        return Err(Error::invalid(
            "theta_max_deg",
            format!("must be in (0, 180], got {theta_max_deg}"),
        ));
    }
    let rows: Vec<[f32; 3]> = maps.points.iter().map(|p| p.to_array()).collect();
    let tree = Tree::new_from_slice(&rows);
    // The f32 range query is widened by a few ulps; the exact f64 test below decides.
    let r2 = (d_max * (1.0 + 1e-5)).powi(2) as f32;
    let out: Vec<(f64, u32)> = with_threads(threads, || {
        (0..maps.len())
            .into_par_iter()
            .with_min_len(64)
            .map(|i| {
                let mut near: Vec<u32> = tree
                    .within_unsorted::<SquaredEuclidean>(&rows[i], r2)
                    .iter()
                    .map(|nb| nb.item)
                    .collect();
                // Summation order fixed by index, not by the tree's traversal.
                near.sort_unstable();
                let mut m = Moments::default();
                for j in near.into_iter().map(|j| j as usize) {
                    if j == i {
                        continue;
                    }
                    let (d, theta) = maps.distance_angle(i, j);
                    if d <= d_max && theta < theta_max_deg {
                        if let Some(r) = maps.rho(i, j) {
                            m.push(r);
                        }
                    }
                }
                if m.count == 0 {
                    (f64::NAN, 0)
                } else {
                    (m.mean, m.count as u32)
                }
            })
            .collect()
    })?;
    Ok(out.into_iter().unzip())
}

#[cfg(test)]
mod tests;
