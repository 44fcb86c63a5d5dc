//! Online means and variances (Welford's update, Chan et al.'s merge), in `f64`.

/// Running mean and variance of a stream of samples. Pushes use Welford's update, which
/// stays accurate when the mean is large against the spread; [`Welford::merge`] combines
/// two streams (Chan, Golub & LeVeque), so partial sums from threads merged in a fixed
/// order give the same bits for any thread count.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Welford {
    /// Samples seen.
    pub n: u64,
    /// Their mean (0 before the first).
    pub mean: f64,
    /// Sum of squared deviations from the mean.
    pub m2: f64,
}

impl Welford {
    /// Adds one sample.
    #[inline]
    pub fn push(&mut self, x: f64) {
        self.n += 1;
        let delta = x - self.mean;
        self.mean += delta / self.n as f64;
        self.m2 += delta * (x - self.mean);
    }

    /// Adds every sample of `other` (as if they had been pushed after this stream's).
    pub fn merge(&mut self, other: &Welford) {
        if other.n == 0 {
            return;
        }
        if self.n == 0 {
            *self = *other;
            return;
        }
        let n = self.n + other.n;
        let delta = other.mean - self.mean;
        let share = other.n as f64 / n as f64;
        self.mean += delta * share;
        self.m2 += other.m2 + delta * delta * self.n as f64 * share;
        self.n = n;
    }

    /// The sample variance (`n - 1` in the denominator; 0 with fewer than two samples):
    /// an unbiased estimate of the variance of one sample.
    pub fn variance(&self) -> f64 {
        if self.n < 2 {
            0.0
        } else {
            (self.m2 / (self.n - 1) as f64).max(0.0)
        }
    }

    /// The variance of the mean, [`Welford::variance`] over `n` (0 without samples).
    pub fn variance_of_mean(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            self.variance() / self.n as f64
        }
    }
}

/// The variance of a binary variable of mean `m` (SBF §3: visibility is 0 or 1, so
/// `Var(V) = E[V](1 − E[V])`), clamped to `[0, 1/4]` for `m` outside `[0, 1]`.
pub fn binary_variance(m: f64) -> f64 {
    (m * (1.0 - m)).clamp(0.0, 0.25)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::SampleRng;

    #[test]
    fn welford_matches_a_two_pass_reference_far_from_zero() {
        // 1e7 samples offset by 1e6: the naive sum of squares loses every digit here.
        let rng = SampleRng::new(7, 0, 0);
        let n = 10_000_000u64;
        let x = |i: u64| 1e6 + rng.get(i) as f64;
        let mut w = Welford::default();
        for i in 0..n {
            w.push(x(i));
        }
        let mean: f64 = (0..n).map(|i| x(i) - 1e6).sum::<f64>() / n as f64 + 1e6;
        let var: f64 = (0..n).map(|i| (x(i) - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        assert!(
            ((w.mean - mean) / mean).abs() <= 1e-9,
            "{} {}",
            w.mean,
            mean
        );
        assert!(
            ((w.variance() - var) / var).abs() <= 1e-9,
            "{} {var}",
            w.variance()
        );
    }

    #[test]
    fn merging_equals_pushing_in_order_and_binary_variance_is_the_sampled_one() {
        let rng = SampleRng::new(3, 1, 0);
        let samples: Vec<f64> = (0..1000).map(|i| (rng.get(i) < 0.3) as u8 as f64).collect();
        let mut all = Welford::default();
        samples.iter().for_each(|&x| all.push(x));
        let mut merged = Welford::default();
        for chunk in samples.chunks(137) {
            let mut part = Welford::default();
            chunk.iter().for_each(|&x| part.push(x));
            merged.merge(&part);
        }
        assert_eq!(merged.n, all.n);
        assert!((merged.mean - all.mean).abs() < 1e-15);
        assert!((merged.variance() - all.variance()).abs() < 1e-14);
        // For 0/1 samples the sample variance is m (1 - m) n / (n - 1) exactly.
        let n = all.n as f64;
        let expect = binary_variance(all.mean) * n / (n - 1.0);
        assert!(
            (all.variance() - expect).abs() < 1e-13,
            "{} {expect}",
            all.variance()
        );
        assert_eq!(Welford::default().variance(), 0.0);
        assert_eq!(binary_variance(0.0), 0.0);
        assert_eq!(binary_variance(1.0), 0.0);
        assert_eq!(binary_variance(1.5), 0.0);
    }
}
