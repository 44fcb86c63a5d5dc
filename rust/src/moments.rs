//! Online moments of a stream of values: Welford's update and Chan, Golub & LeVeque's merge,
//! in `f64`. Partial moments from threads merged in a fixed order give the same bits for
//! any thread count.

/// Count, mean and sum of squared deviations of a stream of values (Welford), mergeable
/// (Chan, Golub & LeVeque 1979).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Moments {
    /// Values seen.
    pub count: u64,
    /// Their mean (0 when `count == 0`).
    pub mean: f64,
    /// Sum of squared deviations from the mean.
    pub m2: f64,
}

impl Moments {
    /// Adds one value.
    #[inline]
    pub fn push(&mut self, x: f64) {
        self.count += 1;
        let delta = x - self.mean;
        self.mean += delta / self.count as f64;
        self.m2 += delta * (x - self.mean);
    }

    /// [`Moments::push`] of `x[k]` into `moments[k]` for moments that have all seen the
    /// same count (the channels of one stream): one division serves them all, which makes
    /// the last bits differ from `push`'s, not the accuracy.
    #[inline]
    pub fn push_each<const N: usize>(moments: &mut [Moments; N], x: [f64; N]) {
        let count = moments.first().map_or(0, |m| m.count) + 1;
        let inv = 1.0 / count as f64;
        for (m, x) in moments.iter_mut().zip(x) {
            debug_assert_eq!(m.count + 1, count, "push_each needs equal counts");
            m.count = count;
            let delta = x - m.mean;
            m.mean += delta * inv;
            m.m2 += delta * (x - m.mean);
        }
    }

    /// Adds every value `other` has seen.
    pub fn merge(&mut self, other: &Moments) {
        if other.count == 0 {
            return;
        }
        if self.count == 0 {
            *self = *other;
            return;
        }
        let n = (self.count + other.count) as f64;
        let delta = other.mean - self.mean;
        self.mean += delta * other.count as f64 / n;
        self.m2 += other.m2 + delta * delta * self.count as f64 * other.count as f64 / n;
        self.count += other.count;
    }

    /// The sample variance `m2 / (count − 1)` (0 with fewer than two values): an unbiased
    /// estimate of the variance of one value.
    pub fn variance(&self) -> f64 {
        if self.count < 2 {
            0.0
        } else {
            (self.m2 / (self.count - 1) as f64).max(0.0)
        }
    }

    /// The variance of the mean, [`Moments::variance`] over `count` (0 when empty).
    pub fn variance_of_mean(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.variance() / self.count as f64
        }
    }

    /// Population standard deviation `sqrt(m2 / count)` (NaN when empty).
    pub fn std(&self) -> f64 {
        if self.count == 0 {
            f64::NAN
        } else {
            (self.m2 / self.count as f64).max(0.0).sqrt()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimators::decoupled::bound::binary_variance;
    use crate::sampling::rng::SampleRng;

    #[test]
    fn welford_matches_a_two_pass_reference_far_from_zero() {
        // 1e7 samples offset by 1e6: the naive sum of squares loses every digit here.
        let rng = SampleRng::new(7, 0, 0);
        let n = 10_000_000u64;
        let x = |i: u64| 1e6 + rng.get(i) as f64;
        let mut w = Moments::default();
        // The same stream through `push_each`, beside a constant channel.
        let mut each = [Moments::default(); 2];
        for i in 0..n {
            w.push(x(i));
            Moments::push_each(&mut each, [x(i), 1.0]);
        }
        let mean: f64 = (0..n).map(|i| x(i) - 1e6).sum::<f64>() / n as f64 + 1e6;
        let var: f64 = (0..n).map(|i| (x(i) - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        for w in [w, each[0]] {
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
        assert_eq!(
            (each[1].count, each[1].mean, each[1].variance()),
            (n, 1.0, 0.0)
        );
    }

    #[test]
    fn merging_equals_pushing_in_order_and_binary_variance_is_the_sampled_one() {
        let rng = SampleRng::new(3, 1, 0);
        let samples: Vec<f64> = (0..1000).map(|i| (rng.get(i) < 0.3) as u8 as f64).collect();
        let mut all = Moments::default();
        samples.iter().for_each(|&x| all.push(x));
        let mut merged = Moments::default();
        for chunk in samples.chunks(137) {
            let mut part = Moments::default();
            chunk.iter().for_each(|&x| part.push(x));
            merged.merge(&part);
        }
        assert_eq!(merged.count, all.count);
        assert!((merged.mean - all.mean).abs() < 1e-15);
        assert!((merged.variance() - all.variance()).abs() < 1e-14);
        // For 0/1 samples the sample variance is m (1 - m) n / (n - 1) exactly.
        let n = all.count as f64;
        let expect = binary_variance(all.mean) * n / (n - 1.0);
        assert!(
            (all.variance() - expect).abs() < 1e-13,
            "{} {expect}",
            all.variance()
        );
        assert_eq!(Moments::default().variance(), 0.0);
        assert_eq!(binary_variance(0.0), 0.0);
        assert_eq!(binary_variance(1.0), 0.0);
        assert_eq!(binary_variance(1.5), 0.0);
    }
}
