//! Hierarchical piecewise-constant 2D distributions on a `2^L x 2^L` grid: a quadtree of
//! sums (a mip pyramid) stored level by level in Morton order, sampled by hierarchical
//! warping (McCool & Harwood 1997; pbrt-v4's `WindowedPiecewiseConstant2D` does the same
//! with a flat CDF). One 2D uniform sample descends the tree, choosing the column by `u.x`
//! and then the row by `u.y` at every level and rescaling what is left, so stratification
//! survives the warp and the map is invertible ([`QuadPyramid::invert`]).
//!
//! Product sampling (CAM08 §5.5) starts the descent at a node of any level: a sample first
//! picks a cell of a coarse product distribution, then continues down the environment
//! map's own pyramid inside that cell ([`QuadPyramid::descend`]).

use glam::{DVec2, UVec2};

use super::octahedral::{morton_decode, morton_encode};
use crate::error::{Error, Result};

/// Largest `u` below one in `f64`, so a rescaled sample never reaches the upper edge.
const ONE_MINUS_EPSILON: f64 = 1.0 - f64::EPSILON / 2.0;

/// Levels below a descent's start whose weights [`QuadPyramid::descend`] prefetches.
const PREFETCH_LEVELS: usize = 3;

/// A quadtree of non-negative weights over a `2^L x 2^L` grid.
///
/// Invariants: `levels[k]` holds the `4^k` node sums of level `k` in Morton order; the
/// children of node `i` of level `k` are `4i..4i+4` of level `k + 1`; sums are accumulated in
/// `f64` and every weight is finite and `>= 0`.
#[derive(Clone, Debug)]
pub struct QuadPyramid {
    levels: Vec<Vec<f64>>,
    /// Every positive weight and sum lies in `[2^-500, 2^500]`, where [`Fraction`]'s
    /// products neither underflow nor overflow; otherwise descents divide.
    fractions_exact: bool,
}

impl QuadPyramid {
    /// Builds the pyramid over `weights`, given in **row-major** order (`y * side + x`) on a
    /// square grid whose side is a power of two. Fails on a non-square or non-power-of-two
    /// grid and on negative, NaN or infinite weights (naming the first bad cell).
    pub fn from_row_major(weights: &[f64], name: &str) -> Result<Self> {
        let side = (weights.len() as f64).sqrt() as usize;
        if side * side != weights.len() || !side.is_power_of_two() {
            return Err(Error::invalid(
                name,
                format!(
                    "{} weights do not form a square grid with a power-of-two side",
                    weights.len()
                ),
            ));
        }
        if let Some(i) = weights.iter().position(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::invalid(
                name,
                format!(
                    "weight at (x={}, y={}) is {}; weights must be finite and >= 0",
                    i % side,
                    i / side,
                    weights[i]
                ),
            ));
        }
        let mut finest = vec![0.0; weights.len()];
        for (i, &w) in weights.iter().enumerate() {
            finest[morton_encode((i % side) as u32, (i / side) as u32) as usize] = w;
        }
        Ok(Self::from_morton_unchecked(finest))
    }

    /// Builds the pyramid over weights already in Morton order. The caller guarantees a
    /// power-of-four length and finite, non-negative weights (checked in debug builds).
    pub fn from_morton_unchecked(finest: Vec<f64>) -> Self {
        debug_assert!(
            finest.len().is_power_of_two() && finest.len().trailing_zeros().is_multiple_of(2)
        );
        debug_assert!(finest.iter().all(|w| w.is_finite() && *w >= 0.0));
        let depth = finest.len().trailing_zeros() / 2;
        let mut levels = Vec::with_capacity(depth as usize + 1);
        levels.push(finest);
        while levels.last().unwrap().len() > 1 {
            let fine = levels.last().unwrap();
            let coarse = fine
                .chunks_exact(4)
                .map(|c| (c[0] + c[1]) + (c[2] + c[3]))
                .collect();
            levels.push(coarse);
        }
        levels.reverse();
        let smallest =
            levels
                .last()
                .unwrap()
                .iter()
                .fold(f64::INFINITY, |m, &w| if w > 0.0 { m.min(w) } else { m });
        let fractions_exact =
            smallest >= FRACTION_WEIGHT_MIN && levels[0][0] <= 1.0 / FRACTION_WEIGHT_MIN;
        Self {
            levels,
            fractions_exact,
        }
    }

    /// `L`: the finest level; the grid side is `2^L`.
    pub fn depth(&self) -> u32 {
        (self.levels.len() - 1) as u32
    }

    /// Grid side of the finest level.
    pub fn side(&self) -> u32 {
        1 << self.depth()
    }

    /// Sum of all weights.
    pub fn total(&self) -> f64 {
        self.levels[0][0]
    }

    /// Node sums of `level`, in Morton order.
    pub fn level(&self, level: u32) -> &[f64] {
        &self.levels[level as usize]
    }

    /// Weight of a finest-level cell.
    pub fn weight(&self, cell: UVec2) -> f64 {
        self.levels[self.depth() as usize][morton_encode(cell.x, cell.y) as usize]
    }

    /// Probability of a finest-level cell: its weight over the total (0 when all are 0).
    pub fn probability(&self, cell: UVec2) -> f64 {
        let total = self.total();
        if total > 0.0 {
            self.weight(cell) / total
        } else {
            0.0
        }
    }

    /// Samples a finest-level cell with probability [`Self::probability`] from `u ∈ [0,1)^2`.
    /// Returns the cell and the point inside it in `[0,1)^2` (what is left of `u`, uniform
    /// in the cell). `None` when all weights are zero.
    pub fn sample(&self, u: DVec2) -> Option<(UVec2, DVec2)> {
        if self.total() > 0.0 {
            Some(self.descend(0, 0, u))
        } else {
            None
        }
    }

    /// Continues a descent from node `node` (Morton index) of level `level` to the finest
    /// level, choosing children in proportion to their sums. The node's own sum must be
    /// positive. Returns the finest cell and the point inside it.
    pub fn descend(&self, level: u32, node: u32, u: DVec2) -> (UVec2, DVec2) {
        let u = u.clamp(DVec2::ZERO, DVec2::splat(ONE_MINUS_EPSILON));
        if !self.fractions_exact {
            return self.descend_dividing(level, node, u);
        }
        let (mut x_left, mut y_left) = (Fraction::new(u.x), Fraction::new(u.y));
        let mut node = node as usize;
        self.prefetch_below(level, node);
        for fine in &self.levels[level as usize + 1..] {
            let c = &fine[4 * node..4 * node + 4];
            // Children in Morton order: (0,0), (1,0), (0,1), (1,1).
            let left = c[0] + c[2];
            let right = c[1] + c[3];
            // The row is split for both columns at once, so that neither waits for the
            // column's choice: one chain of multiplications a level.
            let (x_next, column) = x_left.split(left, right);
            let (y_in_left, row_in_left) = y_left.split(c[0], c[2]);
            let (y_in_right, row_in_right) = y_left.split(c[1], c[3]);
            x_left = x_next;
            y_left = column.pick_fraction(y_in_right, y_in_left);
            let (x, y) = (column.index(), {
                let (l, r) = (row_in_left.index(), row_in_right.index());
                l ^ ((l ^ r) & column.index())
            });
            node = 4 * node + (y << 1 | x);
        }
        (
            morton_decode(node as u32),
            DVec2::new(x_left.value(), y_left.value()),
        )
    }

    /// [`Self::descend`] rescaling `u` by a division at every choice, for weights beyond
    /// the range of [`Fraction`]'s products.
    fn descend_dividing(&self, level: u32, node: u32, mut u: DVec2) -> (UVec2, DVec2) {
        let mut node = node as usize;
        for fine in &self.levels[level as usize + 1..] {
            let c = &fine[4 * node..4 * node + 4];
            let x = split(&mut u.x, c[0] + c[2], c[1] + c[3]);
            let y = split(&mut u.y, c[x], c[x + 2]);
            node = 4 * node + (y << 1 | x);
        }
        (morton_decode(node as u32), u)
    }

    /// Asks for the cache lines of node `node`'s descendants on the next
    /// [`PREFETCH_LEVELS`] levels at once: a descent reads one line per level, each
    /// address known only after the level above is chosen, a chain of misses on a map's
    /// pyramid larger than L2. Subtrees of at most 64 weights, so that a descent from the
    /// root asks for nothing.
    #[inline]
    fn prefetch_below(&self, level: u32, node: usize) {
        if level == 0 {
            return;
        }
        let fine = &self.levels[level as usize + 1..];
        for (d, weights) in fine.iter().take(PREFETCH_LEVELS).enumerate() {
            let count = 4usize << (2 * d);
            let first = node * count;
            for i in (first..first + count).step_by(8) {
                crate::spatial::prefetch(&weights[i]);
            }
        }
    }

    /// The inverse of [`Self::sample`]: the `u` that lands on point `within ∈ [0,1)^2` of
    /// finest cell `cell`. Cells of zero probability have no preimage (`None`).
    pub fn invert(&self, cell: UVec2, within: DVec2) -> Option<DVec2> {
        self.invert_from(0, cell, within)
    }

    /// The inverse of [`Self::descend`] started at level `level`: the `u` that the descent
    /// from `cell`'s ancestor at `level` maps to point `within` of `cell`.
    pub fn invert_from(&self, level: u32, cell: UVec2, within: DVec2) -> Option<DVec2> {
        let depth = self.depth();
        let mut u = within;
        let mut node = morton_encode(cell.x, cell.y) as usize;
        if self.levels[depth as usize][node] <= 0.0 {
            return None;
        }
        for k in (level + 1..=depth).rev() {
            let parent = node >> 2;
            let c = &self.levels[k as usize][4 * parent..4 * parent + 4];
            let (x, y) = (node & 1, (node >> 1) & 1);
            unsplit(&mut u.y, y, c[x], c[x + 2]);
            unsplit(&mut u.x, x, c[0] + c[2], c[1] + c[3]);
            node = parent;
        }
        Some(u)
    }
}

/// What is left of one coordinate of a descent's sample, `u = n / d` with `0 <= u < 1`,
/// kept as a fraction so that a level's choice costs multiplications only: rescaling `u`
/// itself takes a division per choice, and the sixteen choices of a product sample's
/// descent form one dependent chain. Each choice rounds as the division did (the
/// cancellation in `n·(a+b) − a·d` is that of `u·(a+b) − a`), and `d` is kept within
/// `2^±512` by exact powers of two.
#[derive(Clone, Copy, Debug)]
struct Fraction {
    n: f64,
    d: f64,
}

impl Fraction {
    fn new(u: f64) -> Self {
        Self { n: u, d: 1.0 }
    }

    /// Chooses side 1 with probability `b / (a + b)`; returns what is left of the
    /// fraction, uniform in `[0,1)` inside the chosen side, and the side. A zero-weight
    /// side is never chosen.
    #[inline]
    fn split(self, a: f64, b: f64) -> (Self, Side) {
        let scaled = self.n * (a + b);
        let boundary = a * self.d;
        let right = Side::of(
            (scaled >= boundary && b > 0.0) || a <= 0.0,
            scaled,
            boundary,
            a,
            b,
        );
        let num = scaled - right.pick(boundary, 0.0);
        let den = right.pick(b * self.d, boundary);
        // `num < den` but for rounding on the right side (on the left it is the test).
        let mut next = Self {
            n: num.clamp(0.0, den * ONE_MINUS_EPSILON),
            d: den,
        };
        if !(FRACTION_MIN..=FRACTION_MAX).contains(&next.d) {
            let scale = if next.d < FRACTION_MIN {
                FRACTION_MAX
            } else {
                FRACTION_MIN
            };
            next.n *= scale;
            next.d *= scale;
        }
        (next, right)
    }

    /// `n / d`, in `[0, 1)`.
    #[inline]
    fn value(self) -> f64 {
        (self.n / self.d).clamp(0.0, ONE_MINUS_EPSILON)
    }
}

/// A side chosen by [`Fraction::split`], selecting values without a branch: the side is
/// random, so a branch on it is mispredicted half the time, and LLVM turns a plain
/// select here into one (sixteen mispredictions made most of a product sample's 186 ns).
/// On x86-64 it is an SSE2 lane mask, which LLVM keeps as masks.
#[derive(Clone, Copy, Debug)]
struct Side(
    #[cfg(target_arch = "x86_64")] std::arch::x86_64::__m128d,
    #[cfg(not(target_arch = "x86_64"))] bool,
);

impl Side {
    /// Side 1 where `(scaled >= boundary && b > 0) || a <= 0` (`right`, the same test
    /// for other architectures).
    #[inline]
    #[allow(unused_variables)]
    fn of(right: bool, scaled: f64, boundary: f64, a: f64, b: f64) -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::*;
            // SAFETY: SSE2 is part of x86-64.
            unsafe {
                let ge = _mm_cmpge_sd(_mm_set_sd(scaled), _mm_set_sd(boundary));
                let positive = _mm_cmpgt_sd(_mm_set_sd(b), _mm_setzero_pd());
                let empty = _mm_cmple_sd(_mm_set_sd(a), _mm_setzero_pd());
                Self(_mm_or_pd(_mm_and_pd(ge, positive), empty))
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        Self(right)
    }

    /// 0 or 1.
    #[inline]
    fn index(self) -> usize {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: SSE2 is part of x86-64.
        unsafe {
            (std::arch::x86_64::_mm_movemask_pd(self.0) & 1) as usize
        }
        #[cfg(not(target_arch = "x86_64"))]
        (self.0 as usize)
    }

    /// `if_one` on side 1, else `if_zero`.
    #[inline]
    fn pick(self, if_one: f64, if_zero: f64) -> f64 {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: SSE2 is part of x86-64.
        unsafe {
            use std::arch::x86_64::*;
            let (one, zero) = (_mm_set_sd(if_one), _mm_set_sd(if_zero));
            _mm_cvtsd_f64(_mm_or_pd(
                _mm_and_pd(self.0, one),
                _mm_andnot_pd(self.0, zero),
            ))
        }
        #[cfg(not(target_arch = "x86_64"))]
        if self.0 {
            if_one
        } else {
            if_zero
        }
    }

    /// The fraction on side 1, else the other.
    #[inline]
    fn pick_fraction(self, if_one: Fraction, if_zero: Fraction) -> Fraction {
        Fraction {
            n: self.pick(if_one.n, if_zero.n),
            d: self.pick(if_one.d, if_zero.d),
        }
    }
}

/// Least positive weight for which descents use [`Fraction`]s (2^-500; the largest total
/// is its inverse): with the denominator kept within `2^±512`, products of weights and
/// denominators then stay within `2^±1012`, normal `f64`s.
const FRACTION_WEIGHT_MIN: f64 = f64::from_bits((1023 - 500) << 52);

/// Bounds of a [`Fraction`]'s denominator (exact powers of two, each the other's inverse).
const FRACTION_MIN: f64 = 1.0 / FRACTION_MAX;
const FRACTION_MAX: f64 = f64::from_bits((1023 + 512) << 52);

/// Chooses side 0 with probability `a / (a + b)` and rescales `u` to `[0,1)` inside the
/// chosen side, by a division; a zero-weight side is never chosen.
#[inline]
fn split(u: &mut f64, a: f64, b: f64) -> usize {
    let t = *u * (a + b);
    let right = (t >= a && b > 0.0) || a <= 0.0;
    let (num, den) = if right { (t - a, b) } else { (t, a) };
    *u = (num / den).clamp(0.0, ONE_MINUS_EPSILON);
    right as usize
}

/// The inverse of [`split`] and [`Fraction::split`].
#[inline]
fn unsplit(u: &mut f64, side: usize, a: f64, b: f64) {
    let p = a / (a + b);
    *u = if side == 0 {
        *u * p
    } else {
        p + *u * (1.0 - p)
    };
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::{hash4, to_unit_f64};

    fn uniform(i: u64) -> DVec2 {
        DVec2::new(
            to_unit_f64(hash4(3, i, 0, 0)),
            to_unit_f64(hash4(3, i, 0, 1)),
        )
    }

    fn weights(side: usize) -> Vec<f64> {
        (0..side * side)
            .map(|i| {
                let (x, y) = ((i % side) as f64, (i / side) as f64);
                (1.0 + (x * 0.7).sin() * (y * 0.3).cos()).powi(3)
            })
            .collect()
    }

    #[test]
    fn sampled_frequencies_match_probabilities() {
        let side = 16;
        let w = weights(side);
        let pyramid = QuadPyramid::from_row_major(&w, "w").unwrap();
        let n = 2_000_000u64;
        let mut counts = vec![0u64; side * side];
        for i in 0..n {
            let (cell, within) = pyramid.sample(uniform(i)).unwrap();
            assert!(within.x < 1.0 && within.y < 1.0 && within.min_element() >= 0.0);
            counts[cell.y as usize * side + cell.x as usize] += 1;
        }
        // Chi-square over all cells (every expected count is well above 5).
        let total: f64 = w.iter().sum();
        let chi2: f64 = counts
            .iter()
            .zip(&w)
            .map(|(&c, &wi)| {
                let e = n as f64 * wi / total;
                (c as f64 - e).powi(2) / e
            })
            .sum();
        let dof = (side * side - 1) as f64;
        let p = crate::sampling::chi2::chi2_survival(chi2, dof);
        assert!(p > 1e-3, "chi2 = {chi2} for {dof} dof, p = {p}");
    }

    #[test]
    fn invert_is_the_inverse_of_sample() {
        let pyramid = QuadPyramid::from_row_major(&weights(32), "w").unwrap();
        for i in 0..100_000 {
            let u = uniform(i);
            let (cell, within) = pyramid.sample(u).unwrap();
            let back = pyramid.invert(cell, within).unwrap();
            assert!(
                (back - u).abs().max_element() < 1e-9,
                "{u} -> {cell} {within} -> {back}"
            );
        }
    }

    #[test]
    fn zero_weights_are_never_sampled_and_a_single_cell_takes_everything() {
        let mut w = vec![0.0; 64 * 64];
        w[64 * 17 + 5] = 1e-30;
        let pyramid = QuadPyramid::from_row_major(&w, "w").unwrap();
        for i in 0..10_000 {
            let (cell, _) = pyramid.sample(uniform(i)).unwrap();
            assert_eq!(cell, UVec2::new(5, 17));
        }
        assert_eq!(pyramid.probability(UVec2::new(5, 17)), 1.0);
        assert_eq!(pyramid.probability(UVec2::new(6, 17)), 0.0);
        assert!(pyramid
            .invert(UVec2::new(6, 17), DVec2::splat(0.5))
            .is_none());
        // One cell 1e6 above the rest.
        let mut w = vec![1.0; 16 * 16];
        w[3] = 1e6;
        let pyramid = QuadPyramid::from_row_major(&w, "w").unwrap();
        let hits = (0..100_000)
            .filter(|&i| pyramid.sample(uniform(i)).unwrap().0 == UVec2::new(3, 0))
            .count();
        let p: f64 = 1e6 / (1e6 + 255.0);
        let sd = (100_000.0 * p * (1.0 - p)).sqrt();
        assert!((hits as f64 - 100_000.0 * p).abs() < 4.0 * sd + 1.0);
    }

    #[test]
    fn fractions_choose_the_cells_divisions_choose() {
        let pyramid = QuadPyramid::from_row_major(&weights(32), "w").unwrap();
        assert!(pyramid.fractions_exact);
        for i in 0..100_000 {
            let u = uniform(i);
            let (cell, within) = pyramid.descend(0, 0, u);
            let (cell_divided, within_divided) = pyramid.descend_dividing(0, 0, u);
            assert_eq!(cell, cell_divided, "{u}");
            assert!((within - within_divided).abs().max_element() < 1e-12, "{u}");
        }
    }

    #[test]
    fn weights_far_from_one_are_sampled_by_their_ratios() {
        let w = weights(16);
        let pyramid = QuadPyramid::from_row_major(&w, "w").unwrap();
        // Powers of two scale every product exactly: the same cells, the same points,
        // by fractions (2^±400) and by divisions beyond their range (2^-990, 2^600).
        for (exponent, by_fractions) in [(-990, false), (-400, true), (400, true), (600, false)] {
            let scale = 2f64.powi(exponent);
            let scaled: Vec<f64> = w.iter().map(|x| x * scale).collect();
            let far = QuadPyramid::from_row_major(&scaled, "w").unwrap();
            assert_eq!(far.fractions_exact, by_fractions, "2^{exponent}");
            for i in 0..20_000 {
                let u = uniform(i);
                let (cell, within) = far.sample(u).unwrap();
                let (near_cell, near_within) = pyramid.sample(u).unwrap();
                assert_eq!(cell, near_cell, "2^{exponent}, {u}");
                assert!((within - near_within).abs().max_element() < 1e-12);
            }
        }
    }

    #[test]
    fn the_edges_of_the_unit_square_never_reach_a_zero_weight() {
        // Weight only in the lower-left 3x3 cells of 8x8: u at 0, 1 and just below 1.
        let w: Vec<f64> = (0..64)
            .map(|i| {
                if i % 8 < 3 && i / 8 < 3 {
                    1.0 + i as f64
                } else {
                    0.0
                }
            })
            .collect();
        let pyramid = QuadPyramid::from_row_major(&w, "w").unwrap();
        for ux in [0.0, 0.5, ONE_MINUS_EPSILON, 1.0] {
            for uy in [0.0, 0.5, ONE_MINUS_EPSILON, 1.0] {
                let (cell, within) = pyramid.sample(DVec2::new(ux, uy)).unwrap();
                assert!(pyramid.weight(cell) > 0.0, "({ux}, {uy}) -> {cell}");
                assert!(within.max_element() < 1.0 && within.min_element() >= 0.0);
            }
        }
    }

    #[test]
    fn an_all_zero_pyramid_cannot_be_sampled() {
        let pyramid = QuadPyramid::from_row_major(&[0.0; 16], "w").unwrap();
        assert!(pyramid.sample(DVec2::splat(0.5)).is_none());
        assert_eq!(pyramid.probability(UVec2::ZERO), 0.0);
    }

    #[test]
    fn bad_grids_and_weights_are_rejected_with_the_argument_name() {
        for (w, needle) in [
            (vec![1.0; 12], "power-of-two"),
            (vec![1.0; 8], "power-of-two"),
            (vec![1.0, -1.0, 1.0, 1.0], "(x=1, y=0)"),
            (vec![1.0, 1.0, f64::NAN, 1.0], "(x=0, y=1)"),
            (vec![1.0, 1.0, 1.0, f64::INFINITY], "(x=1, y=1)"),
        ] {
            let e = QuadPyramid::from_row_major(&w, "weights")
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("weights:") && e.contains(needle), "{e}");
        }
        let one = QuadPyramid::from_row_major(&[2.0], "w").unwrap();
        assert_eq!(one.depth(), 0);
        assert_eq!(
            one.sample(DVec2::splat(0.3)).unwrap(),
            (UVec2::ZERO, DVec2::splat(0.3))
        );
    }

    #[test]
    fn descent_from_an_inner_node_stays_inside_it() {
        let pyramid = QuadPyramid::from_row_major(&weights(64), "w").unwrap();
        // Node 9 of level 2 is the 16x16 block at (1, 2) of a 4x4 grid of blocks.
        let block = morton_decode(9);
        for i in 0..10_000 {
            let u = uniform(i);
            let (cell, within) = pyramid.descend(2, 9, u);
            assert_eq!(cell / 16, block);
            let back = pyramid.invert_from(2, cell, within).unwrap();
            assert!((back - u).abs().max_element() < 1e-9);
        }
    }
}
