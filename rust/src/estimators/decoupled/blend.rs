//! The blend's share beyond SBF's eq. 11 (module docs of [`super`], "The blend beyond
//! eq. 11: consistent"): the least-error `t` of a pixel and light, and the chi-square
//! upper factor of a sample variance it reads.

use super::*;

/// The least-error `t` of a pixel and light ([`least_error_factor`], module docs) over the
/// channels whose bound `err` allows a bias, the smallest deciding as in eq. 11; 1 (no
/// limit) where no channel's bound is above zero, so that fully lit and fully blocked
/// points keep eq. 11's `1 − ε`. Where stored samples are reused, every channel weighs:
/// their unbiased part may have far less variance than `⟨LB⟩⟨V⟩` even without a bias
/// (a fully lit point whose 64 `LB`-samples face 232 reused ones).
///
/// The squared bias is measured, not taken from the bound: `(⟨LB⟩⟨V⟩ − ⟨LBV⟩)²` less both
/// estimates' variances (unbiased for the square when the two are independent), within
/// `[0, err²]`. The bound, an upper bound that SBF §4.1 finds loose in penumbrae and on
/// glossy surfaces, put in its place cost the first frames: relMSE 1.3-1.6x on garage at
/// threshold 0.25 (`viscache experiment relight`, 2026-11-27). Where stored samples are
/// reused the unbiased part is precise and the measurement is left to `⟨LB⟩`'s noise,
/// which hides biases the bound still allows: the bound is taken as the bias there. At
/// threshold 0.25 (160x120, three seeds, 2026-11-28) that took relMSE from 0.000016 to
/// 0.000012 on the Cornell box after the pattern switch, 0.0074 to 0.0052 on the meshes
/// and 0.059 to 0.048 on garage's other sky, and from 0.049 to 0.063 on garage's rotated
/// map, where the bound is loose. There, too, `⟨LB⟩`'s variance is taken at its upper 95%
/// confidence bound ([`variance_upper_factor`]): from the 16 draws of the experiment's
/// equal-time frames (8 `LB`-, 8 `LBV`-samples) it was often low, and the blend leaned
/// on a noisy `⟨LB⟩` (Cornell box: relMSE 0.0000107 against 0.0000059 for the unbiased
/// part alone; with the bound, 0.0000075). The unbiased part's variance
/// per sample is at least what `⟨V⟩` predicts for a binary `V` independent of `LB/p`,
/// `⟨V⟩ Var(LB/p) + ⟨V⟩(1 − ⟨V⟩)⟨LB⟩²`: eight `LBV`-samples that all missed a sun visible
/// one time in twenty would otherwise report no variance, and the blend would take their
/// zero alone.
pub(super) fn least_error_t(s: &LightSums, v: f64, err: &[f64; 3]) -> f64 {
    (0..3)
        .filter(|&c| err[c] > 0.0 || s.reuse_n > 0.0)
        .filter_map(|c| {
            let (lb, lbv) = (&s.lb[c], &s.lbv[c]);
            // Reused stored samples take the weight `1 − w₂` of the new ones' values, so
            // the floor shrinks by their mean weight squared.
            let w2 = s.new_weight_sum / lbv.count.max(1) as f64;
            let predicted = (v * lb.variance() + binary_variance(v) * lb.mean * lb.mean) * w2 * w2;
            let var_unbiased = lbv.variance().max(predicted) / lbv.count.max(1) as f64
                + s.reused[c].variance_of_mean();
            // Reused samples: `⟨LB⟩`'s variance at its upper 95% confidence bound (the
            // decision turns on it there; from eight or sixteen samples it is often low).
            let var_lb = if s.reuse_n > 0.0 {
                lb.variance_of_mean() * variance_upper_factor(lb.count)
            } else {
                lb.variance_of_mean()
            };
            let var_decoupled = v * v * var_lb;
            let d = v * lb.mean - s.unbiased_mean(c);
            // Reused samples: the bound (above).
            let bias2 = if s.reuse_n > 0.0 {
                err[c] * err[c]
            } else {
                (d * d - var_unbiased - var_decoupled).clamp(0.0, err[c] * err[c])
            };
            least_error_factor(var_unbiased, bias2.sqrt(), var_decoupled)
        })
        .fold(1.0, f64::min)
}

/// `k / χ²₀.₀₅(k)` for `k = count − 1` degrees of freedom: the factor that lifts a sample
/// variance of `count` normal values to its upper 95% confidence bound (the quantile from
/// a table up to 10 degrees of freedom, then Wilson–Hilferty's approximation, within 1%
/// there); 1 below two values. Not statrs's `ChiSquared::inverse_cdf`, which searches the
/// CDF iteratively, where this runs per pixel, light and channel.
pub(super) fn variance_upper_factor(count: u64) -> f64 {
    const QUANTILES: [f64; 10] = [
        0.00393, 0.103, 0.352, 0.711, 1.145, 1.635, 2.167, 2.733, 3.325, 3.940,
    ];
    if count < 2 {
        return 1.0;
    }
    let k = (count - 1) as f64;
    let quantile = match QUANTILES.get(count as usize - 2) {
        Some(&q) => q,
        None => {
            let a = 2.0 / (9.0 * k);
            k * (1.0 - a - 1.645 * a.sqrt()).powi(3)
        }
    };
    k / quantile
}
