//! Adaptive sample counts ([`super::RenderParams::adaptive`]): a pilot pass gives every
//! pixel the same samples, then the rest go where they cut the image's relMSE most.
//!
//! The image's error is `relMSE = (1/P) Σ_i v_i / n_i`, with `v_i` the relative variance
//! of one sample of pixel `i` (per channel `σ² / (μ² + 10⁻²)`, averaged over RGB, the
//! metric of `viscache_rs.metrics`) and `n_i` its samples. For a fixed total `Σ c_i n_i`,
//! `c_i` the cost of one of the pixel's samples, it is least at `n_i ∝ √(v_i / c_i)`
//! (a Lagrange multiplier: Neyman's allocation of stratified sampling, the pixels as
//! strata): that ratio is each pixel's *share*. Without a time budget (a number of
//! samples to spend) every `c_i` is 1; under one, `c_i` is the CPU time per sample the
//! pilot measured. Measured on the suite at 160x120 from 256-spp renders, equal costs,
//! the optimum takes 1.1x (garden, grass everywhere) to 2.5x (garage, a quarter sky)
//! less error than equal counts.
//!
//! ## Unbiased
//! A pixel's share is measured from its neighbours' samples and costs (a 5x5 window
//! without the pixel), not its own: with its own variance, a pixel whose first samples came out low
//! and quiet would take fewer more, a bias toward its first samples. Pixels draw
//! independent random numbers, so what a pixel's count depends on is independent of its
//! samples but for the image-wide terms every pixel adds to, each `1/P` of it: the mean
//! `v` of the defensive term, the scaling of the shares to mean 1, and the scale that
//! spends the budget. Pooling 24 neighbours also measures `v` from 24 times more samples
//! than the pixel has.
//!
//! ## Safeguards
//! - The pilot takes [`PILOT_SHARE`] of the samples evenly; no pixel goes below it, so a
//!   share measured too low (light that the pilot's samples missed) costs at most the
//!   samples the pixel would have had beyond the pilot.
//! - Every share has [`DEFENSIVE`] of the image's mean `v` added.
//! - No pixel takes more than [`CAP_FACTOR`] times the mean.

use super::sums::CvSums;
use crate::math::{RELMSE_FLOOR, WINDOW_RADIUS};

/// Share of the samples the pilot pass spreads evenly before the shares are measured.
/// Measured on the suite (160x120, 100 spp on average): a quarter keeps every scene at
/// or above equal counts; an eighth lost 3-30% on room and garage, whose light the pilot
/// missed in places.
pub const PILOT_SHARE: f64 = 0.25;
/// Below this many samples per pixel on average, every pixel takes the same.
pub const MIN_ADAPTIVE_SPP: u32 = 8;
/// Fraction of the image's mean relative variance added to every pixel's.
pub const DEFENSIVE: f64 = 0.05;
/// Least predicted gain ([`SampleShares::gain`]) for which the shares are kept: below,
/// every pixel takes the same. Shares measured from a pilot are noisy, and where the
/// error is the same everywhere that noise alone costs: garden's grass (predicted 1.02)
/// lost 5-7% of relMSE at 1 s. The prediction understates what the shares give: on the
/// rest of the suite at 1 s it said 1.09-2.7 where they gave 1.15-14x.
pub const MIN_GAIN: f64 = 1.05;
/// Most samples of a pixel, as a multiple of the mean.
pub const CAP_FACTOR: f64 = 16.0;

/// Samples per pixel the pilot takes before a render of `mean` samples per pixel on
/// average, `None` when the render is too short to adapt ([`MIN_ADAPTIVE_SPP`]).
pub fn pilot_spp(mean: u32) -> Option<u32> {
    (mean >= MIN_ADAPTIVE_SPP).then(|| ((mean as f64 * PILOT_SHARE).ceil() as u32).max(2))
}

/// Most samples a pixel of a render of `mean` samples per pixel on average takes
/// ([`CAP_FACTOR`], and at most `max`).
pub fn sample_cap(mean: u32, max: u32) -> u32 {
    ((CAP_FACTOR * mean as f64) as u32).min(max)
}

/// Each pixel's share of the samples after the pilot: `√v` pooled over its neighbours
/// (module docs), scaled to mean 1.
#[derive(Clone, Debug, PartialEq)]
pub struct SampleShares {
    share: Vec<f64>,
    /// The error of even counts over that of these shares, at equal cost, as the pooled
    /// estimates predict it (1 for even shares).
    gain: f64,
}

/// Mean of the values measured in pixel `i`'s window, the pixel itself excluded
/// ([`WINDOW_RADIUS`]); `None` when none is.
fn window_mean(values: &[Option<f64>], i: usize, width: usize, height: usize) -> Option<f64> {
    let (x, y, r) = (i % width, i / width, WINDOW_RADIUS);
    let (mut sum, mut count) = (0.0, 0u32);
    for yy in y.saturating_sub(r)..(y + r + 1).min(height) {
        for xx in x.saturating_sub(r)..(x + r + 1).min(width) {
            if let (false, Some(value)) = ((xx, yy) == (x, y), values[yy * width + xx]) {
                sum += value;
                count += 1;
            }
        }
    }
    (count > 0).then(|| sum / count as f64)
}

impl SampleShares {
    /// Shares from the pilot's sums of a `width x height` image (row-major) with the
    /// control variate's `alpha` per pixel (zeros without it) and, if given, each pixel's
    /// cost per sample (any unit; not finite or not positive: not measured). A pixel with
    /// fewer than two samples measures no variance; a window that measures nothing takes
    /// the image's mean; an image without variance gives every pixel share 1.
    pub fn measure(
        sums: &[CvSums],
        alpha: &[[f64; 3]],
        costs: Option<&[f32]>,
        width: usize,
        height: usize,
    ) -> Self {
        debug_assert_eq!(sums.len(), width * height);
        let v: Vec<Option<f64>> = sums
            .iter()
            .zip(alpha)
            .map(|(s, a)| {
                (s.n >= 2).then(|| {
                    let (mean, var) = s.estimate(*a);
                    let n = s.n as f64;
                    (0..3)
                        .map(|c| var[c] * n / (mean[c] * mean[c] + RELMSE_FLOOR))
                        .sum::<f64>()
                        / 3.0
                })
            })
            .collect();
        Self::from_variances(&v, costs, width, height)
    }

    /// Shares from each pixel's relative variance of one sample `v` (`None`: not
    /// measured), as [`Self::measure`] takes them from its sums: pooled over each pixel's
    /// window, with the defensive term, kept only when their predicted gain is at least
    /// [`MIN_GAIN`].
    pub fn from_variances(
        v: &[Option<f64>],
        costs: Option<&[f32]>,
        width: usize,
        height: usize,
    ) -> Self {
        debug_assert_eq!(v.len(), width * height);
        let measured: Vec<f64> = v.iter().flatten().copied().collect();
        let mean_v = measured.iter().sum::<f64>() / measured.len().max(1) as f64;
        if !(mean_v > 0.0 && mean_v.is_finite()) {
            return Self::even(v.len());
        }
        let c: Vec<Option<f64>> = match costs {
            Some(costs) => costs
                .iter()
                .map(|&c| (c.is_finite() && c > 0.0).then_some(c as f64))
                .collect(),
            None => vec![Some(1.0); v.len()],
        };
        let measured_c: Vec<f64> = c.iter().flatten().copied().collect();
        let mean_c = match measured_c.len() {
            0 => 1.0,
            n => measured_c.iter().sum::<f64>() / n as f64,
        };
        let pooled: Vec<(f64, f64)> = (0..v.len())
            .map(|i| {
                let pooled_v = window_mean(v, i, width, height).unwrap_or(mean_v);
                let pooled_c = window_mean(&c, i, width, height).unwrap_or(mean_c);
                (pooled_v + DEFENSIVE * mean_v, pooled_c)
            })
            .collect();
        // Even counts at cost C give relMSE ∝ Σv Σc; the shares (Σ√(vc))² (Cauchy-Schwarz:
        // never more).
        let (sum_v, sum_c) = pooled
            .iter()
            .fold((0.0, 0.0), |(a, b), &(v, c)| (a + v, b + c));
        let sum_vc = pooled.iter().map(|&(v, c)| (v * c).sqrt()).sum::<f64>();
        let gain = sum_v * sum_c / (sum_vc * sum_vc);
        if gain.is_nan() || gain < MIN_GAIN {
            return Self {
                gain,
                ..Self::even(v.len())
            };
        }
        let mut share: Vec<f64> = pooled.iter().map(|&(v, c)| (v / c).sqrt()).collect();
        let mean_share = share.iter().sum::<f64>() / share.len() as f64;
        for s in &mut share {
            *s /= mean_share;
        }
        Self { share, gain }
    }

    /// These shares with the pixels where `keep(i)` is false left out: share 0, so that
    /// they take no further sample (pixels with nothing to sample).
    pub fn only(mut self, keep: impl Fn(usize) -> bool) -> Self {
        for (i, s) in self.share.iter_mut().enumerate() {
            if !keep(i) {
                *s = 0.0;
            }
        }
        self
    }

    /// Share 1 for each of `pixels` pixels.
    pub fn even(pixels: usize) -> Self {
        Self {
            share: vec![1.0; pixels],
            gain: 1.0,
        }
    }

    /// The predicted error of even counts over that of the shares measured, at equal cost
    /// (also when it fell below [`MIN_GAIN`] and the shares were made even).
    pub fn gain(&self) -> f64 {
        self.gain
    }

    /// Every pixel's share, row-major (mean 1).
    pub fn shares(&self) -> &[f64] {
        &self.share
    }

    /// Pixel `i`'s sample count at scale `lambda`: `λ · share`, rounded, kept between the
    /// samples it has and `cap`.
    #[inline]
    pub fn target(&self, i: usize, lambda: f64, current: u32, cap: u32) -> u32 {
        let want = (lambda * self.share[i]).round().min(cap as f64) as u32;
        want.max(current)
    }

    /// The largest scale whose targets cost at most `spend`, where `cost(i, added)` is
    /// what pixel `i` costs to take `added > 0` more samples (a pixel that takes none costs
    /// nothing). Costs must grow with `added`; the search is a bisection of 64 steps, in
    /// pixel order (the same answer for any thread count).
    pub fn scale_for(
        &self,
        current: &[u32],
        cap: u32,
        spend: f64,
        cost: impl Fn(usize, u32) -> f64,
    ) -> f64 {
        let total = |lambda: f64| -> f64 {
            let mut sum = 0.0;
            for (i, &n) in current.iter().enumerate() {
                let added = self.target(i, lambda, n, cap) - n;
                if added > 0 {
                    sum += cost(i, added);
                }
            }
            sum
        };
        let min_share = self
            .share
            .iter()
            .copied()
            .filter(|&s| s > 0.0)
            .fold(f64::INFINITY, f64::min);
        // Every pixel at the cap: no larger scale adds a sample.
        let mut hi = (cap as f64 + 1.0) / min_share;
        let mut lo = 0.0;
        if total(hi) <= spend {
            return hi;
        }
        for _ in 0..64 {
            let mid = 0.5 * (lo + hi);
            if total(mid) <= spend {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// Sums of `n` samples alternating between `a` and `b` (grey).
    fn sums(n: u32, a: f32, b: f32) -> CvSums {
        let mut s = CvSums::default();
        for k in 0..n {
            let z = if k % 2 == 0 { a } else { b };
            s.add(Vec3::splat(z), [0.0; 3]);
        }
        s
    }

    #[test]
    fn shares_follow_the_neighbours_relative_deviation_and_never_the_pixels_own() {
        // A 9x9 image: the left four columns noisy, the right five quiet.
        let (w, h) = (9, 9);
        let mut image: Vec<CvSums> = (0..w * h)
            .map(|i| {
                if i % w < 4 {
                    sums(8, 0.0, 2.0)
                } else {
                    sums(8, 1.0, 1.0)
                }
            })
            .collect();
        let alpha = vec![[0.0; 3]; w * h];
        let shares = SampleShares::measure(&image, &alpha, None, w, h);
        let s = shares.shares();
        assert!((s.iter().sum::<f64>() / s.len() as f64 - 1.0).abs() < 1e-12);
        // Deep in the noisy side against deep in the quiet side (window of 24 alike):
        // v = var·n/(μ² + 10⁻²) with the sample variance 8/7 and μ = 1 on the left, 0 on
        // the right; the right keeps DEFENSIVE of the mean v.
        let v_noisy = (8.0 / 7.0) / (1.0 + RELMSE_FLOOR);
        let mean_v = v_noisy * (4.0 * 9.0) / 81.0;
        let expected = ((v_noisy + DEFENSIVE * mean_v) / (DEFENSIVE * mean_v)).sqrt();
        let (noisy, quiet) = (s[4 * w + 1], s[4 * w + 7]);
        assert!(
            (noisy / quiet - expected).abs() < 1e-9 * expected,
            "{noisy} {quiet}"
        );
        // A pixel's own samples move its share only through the image's mean (the
        // defensive term and the scaling to mean 1), and move its neighbours' shares.
        // Compare with a pixel outside the changed one's window.
        let (centre, far) = (4 * w + 6, 8 * w);
        image[centre] = sums(8, 0.0, 2.0);
        let after = SampleShares::measure(&image, &alpha, None, w, h);
        let ratio = |s: &[f64], i: usize| s[i] / s[far];
        let (a, b) = (ratio(s, centre), ratio(after.shares(), centre));
        assert!((a - b).abs() <= 0.02 * a, "{a} {b}");
        let (c, d) = (ratio(s, centre + 1), ratio(after.shares(), centre + 1));
        assert!(d > 1.5 * c, "{c} {d}");
        // An image without variance: equal shares.
        let flat = vec![sums(8, 1.0, 1.0); w * h];
        assert!(SampleShares::measure(&flat, &alpha, None, w, h)
            .shares()
            .iter()
            .all(|&x| x == 1.0));
    }

    #[test]
    fn the_scale_spends_the_budget_and_keeps_floor_cap_and_order() {
        let share: Vec<f64> = (0..100).map(|i| 0.1 + (i % 10) as f64 * 0.2).collect();
        let mean = share.iter().sum::<f64>() / share.len() as f64;
        let shares = SampleShares {
            share: share.iter().map(|s| s / mean).collect(),
            gain: 2.0,
        };
        let (current, cap) = (vec![4u32; 100], 40);
        let cost = |_: usize, added: u32| 3.0 + added as f64;
        let spent = |lambda: f64| -> f64 {
            (0..100)
                .map(|i| shares.target(i, lambda, current[i], cap) - current[i])
                .filter(|&added| added > 0)
                .map(|added| cost(0, added))
                .sum()
        };
        for spend in [0.0, 50.0, 500.0, 1500.0, 1e9] {
            let lambda = shares.scale_for(&current, cap, spend, cost);
            let targets: Vec<u32> = (0..100)
                .map(|i| shares.target(i, lambda, current[i], cap))
                .collect();
            assert!(spent(lambda) <= spend, "{} > {spend}", spent(lambda));
            assert!(targets.iter().all(|&t| (4..=cap).contains(&t)));
            // A larger scale overspends, unless every pixel is at the cap.
            let capped = targets.iter().all(|&t| t == cap);
            assert!(capped || spent(lambda * (1.0 + 1e-9) + 1e-12) > spend);
            // More share, at least as many samples.
            for i in 0..100 {
                for j in 0..100 {
                    if shares.shares()[i] < shares.shares()[j] {
                        assert!(targets[i] <= targets[j]);
                    }
                }
            }
        }
    }

    #[test]
    fn short_renders_do_not_adapt() {
        assert_eq!(pilot_spp(7), None);
        assert_eq!(pilot_spp(8), Some(2));
        assert_eq!(pilot_spp(100), Some(25));
        assert_eq!(pilot_spp(101), Some(26));
    }
}
