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

/// A quadtree of non-negative weights over a `2^L x 2^L` grid.
///
/// Invariants: `levels[k]` holds the `4^k` node sums of level `k` in Morton order; the
/// children of node `i` of level `k` are `4i..4i+4` of level `k + 1`; sums are accumulated in
/// `f64` and every weight is finite and `>= 0`.
#[derive(Clone, Debug)]
pub struct QuadPyramid {
    levels: Vec<Vec<f64>>,
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
        Self { levels }
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
        let mut u = u.clamp(DVec2::ZERO, DVec2::splat(ONE_MINUS_EPSILON));
        let mut node = node as usize;
        for fine in &self.levels[level as usize + 1..] {
            let c = &fine[4 * node..4 * node + 4];
            // Children in Morton order: (0,0), (1,0), (0,1), (1,1).
            let left = c[0] + c[2];
            let right = c[1] + c[3];
            let x = split(&mut u.x, left, right);
            let y = split(&mut u.y, c[x], c[x + 2]);
            node = 4 * node + (y << 1 | x);
        }
        (morton_decode(node as u32), u)
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

/// Chooses side 0 with probability `a / (a + b)` and rescales `u` to `[0,1)` inside the
/// chosen side. A zero-weight side is never chosen. Branch-free with one division: the
/// side is random, so a branch on it would be mispredicted half the time (the descent of
/// a product sample makes sixteen of these choices).
#[inline]
fn split(u: &mut f64, a: f64, b: f64) -> usize {
    let t = *u * (a + b);
    let right = t >= a;
    let (num, den) = if right { (t - a, b) } else { (t, a) };
    *u = (num / den).clamp(0.0, ONE_MINUS_EPSILON);
    right as usize
}

/// The inverse of [`split`].
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
