//! Counter-based random numbers: every value is a pure function of
//! `(seed, pixel, sample, dimension)`, so any thread may draw any sample in any order and
//! images come out bit-identical for every thread count. The hash is a chain of SplitMix64
//! finalisers (Steele et al., "Fast splittable pseudorandom number generators", 2014), one
//! per coordinate, which passes the uniformity and independence tests below.

/// SplitMix64's 64-bit finaliser: a bijection with full avalanche.
#[inline(always)]
pub const fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

const GOLDEN: u64 = 0x9e37_79b9_7f4a_7c15;

/// 64 random bits for one coordinate of one sample of one pixel.
#[inline(always)]
pub const fn hash4(seed: u64, pixel: u64, sample: u64, dimension: u64) -> u64 {
    let h = mix64(seed.wrapping_add(GOLDEN));
    let h = mix64(h ^ pixel.wrapping_mul(GOLDEN));
    let h = mix64(h ^ sample.wrapping_add(0x632b_e59b_d9b4_e019));
    mix64(h ^ dimension.wrapping_mul(0xd1b5_4a32_d192_ed03))
}

/// Maps 64 random bits to a float uniform in `[0, 1)` (24 bits of precision).
#[inline(always)]
pub fn to_unit_f32(bits: u64) -> f32 {
    (bits >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
}

/// Maps 64 random bits to a double uniform in `[0, 1)` (53 bits of precision).
#[inline(always)]
pub fn to_unit_f64(bits: u64) -> f64 {
    (bits >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// A source of the random numbers of one pixel sample, by dimension: the estimators draw
/// through it, so the renderer may give them quasi-random samples
/// ([`super::sobol::PixelSampler`]) and tests independent ones ([`SampleRng`]).
pub trait Sampler {
    /// Uniform in `[0, 1)` for dimension `d`.
    fn get(&self, d: u64) -> f32;

    /// Two consecutive dimensions `d, d + 1` as a 2D point in `[0, 1)^2`.
    #[inline]
    fn get2(&self, d: u64) -> [f32; 2] {
        [self.get(d), self.get(d + 1)]
    }

    /// Dimensions `d .. d + 4`, `d` a multiple of 4: one set of a
    /// [`super::sobol::PixelSampler`], made once where four calls of `get` would make it four
    /// times.
    #[inline]
    fn get_set(&self, d: u64) -> [f32; 4] {
        debug_assert!(d.is_multiple_of(4), "a set starts at a multiple of four");
        [
            self.get(d),
            self.get(d + 1),
            self.get(d + 2),
            self.get(d + 3),
        ]
    }
}

impl Sampler for SampleRng {
    #[inline(always)]
    fn get(&self, d: u64) -> f32 {
        SampleRng::get(self, d)
    }
}

/// The random stream of one sample of one pixel: `get(d)` is the value of dimension `d`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SampleRng {
    pub seed: u64,
    pub pixel: u64,
    pub sample: u64,
}

impl SampleRng {
    /// The stream of `(seed, pixel, sample)`.
    pub const fn new(seed: u64, pixel: u64, sample: u64) -> Self {
        Self {
            seed,
            pixel,
            sample,
        }
    }

    /// Uniform in `[0, 1)` for dimension `d`.
    #[inline(always)]
    pub fn get(&self, d: u64) -> f32 {
        to_unit_f32(hash4(self.seed, self.pixel, self.sample, d))
    }

    /// Two consecutive dimensions `d, d + 1` as a 2D point in `[0, 1)^2`.
    #[inline(always)]
    pub fn get2(&self, d: u64) -> [f32; 2] {
        [self.get(d), self.get(d + 1)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pearson chi-square over `bins` equal bins, compared against a bound that a correct
    /// uniform generator exceeds with probability ~1e-6 (mean + 5 standard deviations).
    fn chi2_uniform(values: impl Iterator<Item = f32>, bins: usize) -> (f64, f64) {
        let mut counts = vec![0u64; bins];
        let mut n = 0u64;
        for v in values {
            assert!((0.0..1.0).contains(&v));
            counts[(v * bins as f32) as usize] += 1;
            n += 1;
        }
        let e = n as f64 / bins as f64;
        let chi2: f64 = counts.iter().map(|&c| (c as f64 - e).powi(2) / e).sum();
        let dof = (bins - 1) as f64;
        (chi2, dof + 5.0 * (2.0 * dof).sqrt())
    }

    #[test]
    fn uniform_along_every_coordinate() {
        let n = 200_000u64;
        let streams: [Box<dyn Fn(u64) -> f32>; 4] = [
            Box::new(|i| SampleRng::new(i, 0, 0).get(0)),
            Box::new(|i| SampleRng::new(7, i, 0).get(0)),
            Box::new(|i| SampleRng::new(7, 3, i).get(0)),
            Box::new(|i| SampleRng::new(7, 3, 5).get(i)),
        ];
        for (k, f) in streams.iter().enumerate() {
            let (chi2, bound) = chi2_uniform((0..n).map(f), 256);
            assert!(chi2 < bound, "coordinate {k}: chi2 {chi2} >= {bound}");
        }
    }

    #[test]
    fn pairs_of_dimensions_are_uniform_in_2d() {
        // Joint 16x16 histogram of (dim 0, dim 1) over pixels: catches correlation.
        let n = 256_000u64;
        let vals = (0..n).map(|p| {
            let [a, b] = SampleRng::new(1, p, 0).get2(0);
            ((a * 16.0) as u32 * 16 + (b * 16.0) as u32) as f32 / 256.0 + 1e-6
        });
        let (chi2, bound) = chi2_uniform(vals, 256);
        assert!(chi2 < bound, "chi2 {chi2} >= {bound}");
    }

    #[test]
    fn pure_function_of_its_inputs() {
        let a = SampleRng::new(3, 10, 2);
        assert_eq!(a.get(4), SampleRng::new(3, 10, 2).get(4));
        assert_ne!(a.get(4), SampleRng::new(4, 10, 2).get(4));
        assert_ne!(hash4(0, 1, 0, 0), hash4(0, 0, 1, 0));
        assert!(to_unit_f32(u64::MAX) < 1.0 && to_unit_f64(u64::MAX) < 1.0);
    }
}
