//! The coherence check of [`CacheParams::check_coherence`]: before an empty cache's build
//! inserts records, visibility maps at pairs of pixels as far apart as the records will be
//! predict what the control variate (CAM08 eq. 2-6) gains over product sampling, its own
//! costs included; a build that would not pay inserts none.
//!
//! **The prediction.** For binary visibility `V` and a sample drawn from the unoccluded
//! product `p ∝ L·ρ·cos`, product sampling's estimate is `c·V` (`c = ∫ L ρ cos`), so its
//! variance is `c² v (1 − v)` and its relative variance `(1 − v) / v`, with `v` the visible
//! share. The control variate with a neighbour's record `Ṽ` as the control estimates
//! `c·α·(mean Ṽ) + c·(V − α Ṽ)`: variance `c² Var(V − α Ṽ)`, relative variance that over
//! `v²`; at `α = 1` it is `c² (d − (v − ṽ)²)`, with `d` the share of directions where the two
//! disagree. The check takes the `α` that makes it least (CAM08 eq. 5) for each map of a
//! pair with the other as its record. The render keeps `α = 1` but blends several records,
//! which pulls `Ṽ` toward its mean where neighbouring maps differ, as a small `α` does:
//! with `α = 1` the prediction put the hair of `hairball` at twice product sampling's
//! variance where the render measured 0.5-0.9x. The check sums both relative variances
//! over its pairs (a pair's `v` floored at [`VISIBLE_FLOOR`], as relMSE's `10⁻²` keeps dark
//! pixels from dominating; pairs that see nothing are black either way and are skipped),
//! and [`predicted_gain`] weighs the ratio against what the records cost.
//!
//! [`CacheParams::check_coherence`]: crate::visibility::params::CacheParams::check_coherence

use super::interpolant::ALPHA_MAX;

/// Least visible share a pair's relative variances are computed with: a point seeing one of
/// the check's 256 directions would otherwise weigh 256 times a half-open one.
pub const VISIBLE_FLOOR: f64 = 1.0 / 32.0;

/// The one constant fitted to the suite: how far the control variate's variance ratio
/// exceeds the prediction, which leaves out that records are looked up at other points
/// than the samples' own, `α = 1` in the render, the sun's colours and the jitter's own
/// variance. With records forced (`check_coherence=False`) on the 11 env-lit suite scenes
/// at 256x192 and 640x480, 10 and 100 spp, the decision "records pay" agrees with the
/// measured gain (variance x time, build included) on all 44 cases for any scale in
/// 0.94-1.25 (benches/HISTORY.md, 2026-11-28, fifth session): below it instances at 256x192
/// and 10 spp (measured 0.77) and strands at 640x480 and 100 spp (0.71) would build
/// records, above it hairball at 640x480 and 100 spp (1.45) would not. 1.1 is the middle.
pub const PREDICTION_SCALE: f64 = 1.1;

/// A control-variate sample's time over a product sample's, the per-pixel lookups apart:
/// the two renders' times differ by 1.11-1.14x at 100 spp (instances, hairball;
/// `benches/cv_costs.py`).
pub const CV_SAMPLE_COST: f64 = 1.1;

/// A pixel's records lookup and `J`, in product samples: the control variate took 1.31-1.54
/// times product sampling's time at 10 spp (garage, instances, meshes, room, scales) and
/// 1.11-1.14 at 100.
pub const CV_PIXEL_COST: f64 = 3.0;

/// One 64² record's build, in product samples: 168-485 over garage, scales, room, meshes,
/// instances and hairball (`benches/cv_costs.py`).
pub const RECORD_COST: f64 = 300.0;

/// One pair of the check's visibility maps: the visible share of each and the share of
/// directions where they disagree (all in `[0, 1]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapPair {
    /// Visible share of the first map's directions.
    pub visible_a: f64,
    /// Visible share of the second map's directions.
    pub visible_b: f64,
    /// Share of directions visible in exactly one of the two.
    pub disagree: f64,
}

/// The control variate's relative variance over product sampling's predicted from the
/// check's `pairs` (module docs); `None` when no pair has any visibility variance (nothing
/// occluded and nothing seen alike: the prediction has nothing to go on).
pub fn predicted_variance_ratio(pairs: impl IntoIterator<Item = MapPair>) -> Option<f64> {
    let (mut cv, mut product) = (0.0, 0.0);
    for p in pairs {
        let (a, b) = (p.visible_a, p.visible_b);
        if a == 0.0 && b == 0.0 {
            continue;
        }
        // Each map stands for the point and the other for its neighbour's record.
        let both = (0.5 * (a + b - p.disagree)).max(0.0);
        let relative = |v: f64| (1.0 - v) / v.max(VISIBLE_FLOOR);
        let predicted = |v: f64, v_record: f64| {
            let floor = v.max(VISIBLE_FLOOR);
            residual_variance(v, v_record, both) / (floor * floor)
        };
        cv += 0.5 * (predicted(a, b) + predicted(b, a));
        product += 0.5 * (relative(a) + relative(b));
    }
    (product > 0.0).then(|| cv / product)
}

/// Variance over the directions of `V − α Ṽ` for binary maps with visible shares `v` (the
/// point's) and `v_record` (the record's), visible together on `both`:
/// `Var V − 2α Cov(V, Ṽ) + α² Var Ṽ` at its least over `α ∈ [0, ALPHA_MAX]`, `α* = Cov /
/// Var Ṽ` (CAM08 eq. 4-5, the record as the control). With `α = 1` it is `d − (v − ṽ)²`;
/// the fitted `α` stands for what a blend of several records does where neighbouring maps
/// differ (module docs).
fn residual_variance(v: f64, v_record: f64, both: f64) -> f64 {
    let var = v * (1.0 - v);
    let var_record = v_record * (1.0 - v_record);
    let cov = both - v * v_record;
    let alpha = if var_record > 0.0 {
        (cov / var_record).clamp(0.0, ALPHA_MAX)
    } else {
        0.0
    };
    (var - 2.0 * alpha * cov + alpha * alpha * var_record).max(0.0)
}

/// Efficiency of the control variate over product sampling predicted from `variance_ratio`
/// ([`predicted_variance_ratio`]) for renders of `spp` samples per pixel with
/// `records_per_pixel` records per covered pixel to build: `1 / (PREDICTION_SCALE · ratio
/// · cost)`, the cost in product samples per sample `CV_SAMPLE_COST + (CV_PIXEL_COST +
/// RECORD_COST · records_per_pixel) / spp`. Without `spp` the records serve samples
/// without end (a cache kept across frames) and only the per-sample cost counts. Records
/// pay where this exceeds 1.
pub fn predicted_gain(variance_ratio: f64, spp: Option<u32>, records_per_pixel: f64) -> f64 {
    let per_pixel = CV_PIXEL_COST + RECORD_COST * records_per_pixel;
    let cost = CV_SAMPLE_COST + spp.map_or(0.0, |s| per_pixel / s.max(1) as f64);
    1.0 / (PREDICTION_SCALE * variance_ratio * cost)
}

/// Pixels between the check's pairs: the spacing `sqrt(covered_pixels / records)` of
/// `records` spread evenly over the covered pixels, rounded, at least 1. A lookup's nearest
/// record is about that far away.
pub fn pair_step(covered_pixels: usize, records: usize) -> usize {
    let spacing = (covered_pixels as f64 / records.max(1) as f64).sqrt();
    (spacing.round() as usize).max(1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pair(visible_a: f64, visible_b: f64, disagree: f64) -> MapPair {
        MapPair {
            visible_a,
            visible_b,
            disagree,
        }
    }

    #[test]
    fn identical_maps_predict_no_variance_and_unrelated_ones_that_of_product() {
        // Records equal to the points they serve cancel all variance.
        assert_eq!(predicted_variance_ratio([pair(0.5, 0.5, 0.0)]), Some(0.0));
        // Two independent half-open maps disagree on half the directions: no covariance,
        // so the best α is 0 and the control variate keeps V's own variance.
        let r = predicted_variance_ratio([pair(0.5, 0.5, 0.5)]).unwrap();
        assert!((r - 1.0).abs() < 1e-12, "{r}");
        // Complementary maps: V = 1 - Ṽ, so V - α Ṽ = 1 - (1 + α) Ṽ is least at α = 0
        // (α* = -1, clamped to the allowed range).
        let r = predicted_variance_ratio([pair(0.5, 0.5, 1.0)]).unwrap();
        assert!((r - 1.0).abs() < 1e-12, "{r}");
    }

    #[test]
    fn the_residual_is_least_at_the_fitted_alpha() {
        // One map inside the other: visible on a half and three quarters, together on
        // the half. Against a brute-force scan over α in [0, ALPHA_MAX].
        for (v, v_record, both) in [(0.5, 0.75, 0.5), (0.75, 0.5, 0.5), (0.3, 0.4, 0.2)] {
            let brute = (0..=20_000)
                .map(|i| {
                    let a = ALPHA_MAX * i as f64 / 20_000.0;
                    let cov = both - v * v_record;
                    v * (1.0 - v) - 2.0 * a * cov + a * a * v_record * (1.0 - v_record)
                })
                .fold(f64::INFINITY, f64::min);
            let fitted = residual_variance(v, v_record, both);
            assert!(
                (fitted - brute).abs() < 1e-8,
                "{v} {v_record}: {fitted} {brute}"
            );
        }
        // At α = 1 the residual would be d − Δv²: the fitted one is never above it.
        let (v, v_record, both) = (0.5, 0.75, 0.5);
        let d = v + v_record - 2.0 * both;
        assert!(residual_variance(v, v_record, both) <= d - (v - v_record).powi(2));
        // A record that sees everything is a constant: the point keeps its own variance.
        assert!((residual_variance(0.5, 1.0, 0.5) - 0.25).abs() < 1e-12);
    }

    #[test]
    fn pairs_that_see_nothing_or_everything_are_handled() {
        // Pairs that see nothing are black either way: they do not count.
        let with_black = predicted_variance_ratio([pair(0.5, 0.5, 0.25), pair(0.0, 0.0, 0.0)]);
        assert_eq!(with_black, predicted_variance_ratio([pair(0.5, 0.5, 0.25)]));
        // Nothing occluded anywhere: no variance to predict from.
        assert_eq!(predicted_variance_ratio([pair(1.0, 1.0, 0.0)]), None);
        assert_eq!(predicted_variance_ratio([]), None);
        // A nearly blind point weighs as one at the floor, not 1/v.
        let dark = predicted_variance_ratio([pair(1.0 / 256.0, 1.0 / 256.0, 2.0 / 256.0)]);
        // (The two see different directions: α = 0 leaves V's own variance v (1 − v).)
        let (v, floor) = (1.0 / 256.0, VISIBLE_FLOOR);
        let expected = v * (1.0 - v) / (floor * floor) / ((1.0 - v) / floor);
        assert!((dark.unwrap() - expected).abs() < 1e-12);
    }

    #[test]
    fn the_gain_falls_with_fewer_samples_and_more_records() {
        let many = predicted_gain(0.3, None, 0.1);
        let hundred = predicted_gain(0.3, Some(100), 0.1);
        let ten = predicted_gain(0.3, Some(10), 0.1);
        assert!(many > hundred && hundred > ten, "{many} {hundred} {ten}");
        assert!(predicted_gain(0.3, Some(10), 0.2) < ten);
        let expected = 1.0 / (PREDICTION_SCALE * 0.3 * CV_SAMPLE_COST);
        assert!((many - expected).abs() < 1e-12);
        // spp 0 is read as 1 rather than dividing by zero.
        assert!(predicted_gain(0.3, Some(0), 0.1).is_finite());
    }

    #[test]
    fn pairs_are_spaced_like_the_records() {
        // A tenth of the pixels: records about 3 pixels apart.
        assert_eq!(pair_step(49_152, 4_915), 3);
        // One record per 400 samples at 10 spp: a fortieth of the pixels, about 6 apart.
        assert_eq!(pair_step(49_152, 1_228), 6);
        assert_eq!(pair_step(100, 1_000), 1);
        assert_eq!(pair_step(100, 0), 10);
    }
}
