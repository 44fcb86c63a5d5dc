//! SBF's error of decoupled visibility, its bound and the blend it sets (SBF eq. 4-11).

/// The variance of a binary variable of mean `m` (SBF §3: visibility is 0 or 1, so
/// `Var(V) = E[V](1 − E[V])`), clamped to `[0, 1/4]` for `m` outside `[0, 1]`.
pub fn binary_variance(m: f64) -> f64 {
    (m * (1.0 - m)).clamp(0.0, 0.25)
}

/// `|Err| ≤ sqrt(Var(LB/p) · Var(V))` (SBF eq. 7, from `Err = Cov(LB/p, V)`, eq. 5, and
/// Cauchy–Schwarz): the largest error of replacing visibility by the scalar `E_p[V]`,
/// per channel. Variances are those of one sample under the same density `p`.
pub fn error_bound(var_lb: f64, var_v: f64) -> f64 {
    (var_lb.max(0.0) * var_v.max(0.0)).sqrt()
}

/// SBF eq. 8: [`error_bound`] for uniform sampling of a light of area `area` (`p = 1/A`):
/// `A · sqrt(Var(LB) · Var(V))`, with `Var(LB)` the variance of `LB` itself.
pub fn uniform_error_bound(area: f64, var_lb: f64, var_v: f64) -> f64 {
    area * error_bound(var_lb, var_v)
}

/// The blend factor `t` of SBF eq. 11 from the estimated bound `err` and `⟨LB⟩` per
/// channel: `t = clamp(threshold / Err_rel, 0, 1 − ε)` with `Err_rel = err / ⟨LB⟩`
/// (eq. 10), the channel of the largest relative error deciding. Where a channel's
/// `⟨LB⟩` or bound is (near) zero its relative error counts as zero, and with every
/// channel so `t = 1 − ε` (SBF §4: a relative error there costs little absolute error).
/// `threshold = 0` gives `t = 0`: the unbiased estimator alone.
pub fn blend_factor(err: [f64; 3], lb: [f64; 3], threshold: f64, epsilon: f64) -> f64 {
    let rel = relative_error(err, lb);
    let t = if rel > 0.0 {
        threshold / rel
    } else {
        f64::INFINITY
    };
    if threshold <= 0.0 {
        return 0.0;
    }
    t.clamp(0.0, 1.0 - epsilon)
}

/// SBF eq. 10 over the channels: the largest `err / ⟨LB⟩`, a channel whose `⟨LB⟩` or
/// bound is (near) zero counting as zero ([`blend_factor`]).
pub fn relative_error(err: [f64; 3], lb: [f64; 3]) -> f64 {
    (0..3)
        .map(|c| {
            if lb[c].abs() > f64::MIN_POSITIVE && err[c] > 0.0 {
                err[c] / lb[c].abs()
            } else {
                0.0
            }
        })
        .fold(0.0f64, f64::max)
}

/// The `t` that minimises the blend's expected squared error in one channel, beyond SBF:
/// with `⟨LBV⟩` unbiased of variance `var_unbiased` and `⟨LB⟩⟨V⟩` off by `bias` with
/// variance `var_decoupled`, eq. 9's error is `(1 − t)² var_unbiased + t² (bias² +
/// var_decoupled)` (the two taken as uncorrelated), least at `t = var_unbiased /
/// (var_unbiased + bias² + var_decoupled)`. As `LBV`-samples accumulate, `var_unbiased`
/// falls and so does `t` wherever there is a bias: the blend converges to the unbiased
/// estimator, where eq. 11's `t` keeps the bias however many samples are taken (SBF: "not
/// even consistent"). `None` where nothing weighs (all three zero or not finite).
pub fn least_error_factor(var_unbiased: f64, bias: f64, var_decoupled: f64) -> Option<f64> {
    let total = var_unbiased + bias * bias + var_decoupled;
    (total > 0.0 && total.is_finite()).then(|| (var_unbiased / total).clamp(0.0, 1.0))
}

/// SBF eq. 9: `(1 − t) ⟨LBV⟩ + t ⟨LB⟩ ⟨V⟩`.
pub fn blend(lbv: f64, lb: f64, v: f64, t: f64) -> f64 {
    (1.0 - t) * lbv + t * lb * v
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::SampleRng;

    /// `(∫ LB V − ∫ LB · E_p[V], Cov(LB/p, V), bound with exact variances)` of functions on
    /// `[0, 1)` by the midpoint rule on `n` points, `p` a density on `[0, 1)`.
    fn quadrature(
        lb: impl Fn(f64) -> f64,
        v: impl Fn(f64) -> f64,
        p: impl Fn(f64) -> f64,
        n: usize,
    ) -> (f64, f64, f64) {
        let xs: Vec<f64> = (0..n).map(|i| (i as f64 + 0.5) / n as f64).collect();
        let dx = 1.0 / n as f64;
        let int = |f: &dyn Fn(f64) -> f64| xs.iter().map(|&x| f(x)).sum::<f64>() * dx;
        let (lbv, lb_int) = (int(&|x| lb(x) * v(x)), int(&|x| lb(x)));
        let ev = int(&|x| v(x) * p(x));
        let err = lbv - lb_int * ev;
        // Under p: E[LB/p] = ∫ LB, E[LB/p · V] = ∫ LB V.
        let e_ratio = int(&|x| lb(x) / p(x) * p(x));
        let cov = int(&|x| (lb(x) / p(x) - e_ratio) * (v(x) - ev) * p(x));
        let var_lb = int(&|x| (lb(x) / p(x) - e_ratio).powi(2) * p(x));
        let var_v = int(&|x| (v(x) - ev).powi(2) * p(x));
        (err, cov, error_bound(var_lb, var_v))
    }

    #[test]
    fn the_error_is_the_covariance_and_the_bound_holds() {
        // Random lights (sums of bumps), occluders (unions of intervals, penumbra-like
        // ramps) and densities (uniform and importance-shaped).
        let rng = SampleRng::new(11, 0, 0);
        for case in 0..200u64 {
            let r = |k: u64| rng.get(case * 64 + k) as f64;
            let (c1, c2, w) = (r(0), r(1), 0.02 + 0.3 * r(2));
            let sharp = 1.0 + 40.0 * r(3);
            let lb = move |x: f64| {
                1e-3 + (-((x - c1) / w).powi(2)).exp() + sharp * (-((x - c2) * 10.0).powi(2)).exp()
            };
            let (a, b, ramp) = (r(4) * 0.8, r(5) * 0.5, 1e-3 + 0.1 * r(6));
            let v = move |x: f64| ((x - a) / ramp).clamp(0.0, 1.0) * (x > a + b) as u8 as f64;
            let importance = case % 2 == 1;
            let p = move |x: f64| if importance { 0.5 + x } else { 1.0 };
            let (err, cov, bound) = quadrature(lb, v, p, 20_000);
            let scale = err.abs().max(cov.abs()).max(1e-12);
            assert!(
                (err - cov).abs() <= 1e-6 * scale,
                "case {case}: {err} vs {cov}"
            );
            assert!(
                err.abs() <= bound * (1.0 + 1e-9) + 1e-15,
                "case {case}: {err} > {bound}"
            );
        }
    }

    #[test]
    fn uniform_bound_and_blend_factor() {
        assert_eq!(uniform_error_bound(2.0, 4.0, 0.25), 2.0);
        // Relative errors 0.5 and 2: the worst channel sets t = 0.25 / 2.
        let t = blend_factor([1.0, 2.0, 0.0], [2.0, 1.0, 0.0], 0.25, 0.1);
        assert!((t - 0.125).abs() < 1e-15);
        // No error anywhere (fully lit or blocked), or no light: t = 1 - ε.
        assert_eq!(blend_factor([0.0; 3], [1.0; 3], 0.25, 0.1), 0.9);
        assert_eq!(blend_factor([1.0; 3], [0.0; 3], 0.25, 0.1), 0.9);
        // A small error against the threshold is clamped to 1 - ε.
        assert_eq!(blend_factor([1e-3; 3], [1.0; 3], 0.25, 0.1), 0.9);
        // Threshold 0: the unbiased estimator alone.
        assert_eq!(blend_factor([1.0; 3], [1.0; 3], 0.0, 0.1), 0.0);
        // The least-error factor: variances 1 and bias 0 weigh the two alike; a bias of 3
        // against an unbiased variance of 1 leaves a tenth to the decoupled part.
        assert_eq!(least_error_factor(1.0, 0.0, 1.0), Some(0.5));
        assert_eq!(least_error_factor(1.0, 3.0, 0.0), Some(0.1));
        assert_eq!(least_error_factor(0.0, 2.0, 1.0), Some(0.0));
        assert_eq!(least_error_factor(0.0, 0.0, 0.0), None);
        assert_eq!(least_error_factor(f64::INFINITY, 1.0, 0.0), None);
        assert_eq!(blend(2.0, 3.0, 0.5, 0.0), 2.0);
        assert_eq!(blend(2.0, 3.0, 0.5, 1.0), 1.5);
    }
}
