//! Per-pixel quasi-random samples for the renderer: Owen-scrambled Sobol points (Burley,
//! "Practical Hash-based Owen Scrambling", JCGT 2020, through the `sobol_burley` crate),
//! padded in sets of four dimensions.
//!
//! Sample `s` of pixel `p` is point `s` of a 4D Sobol sequence for each set of four
//! dimensions; each (seed, pixel, set) scrambles and shuffles its sequence independently,
//! so sets are mutually independent and every single sample is uniformly distributed
//! (estimates stay unbiased), while the samples of one pixel fill each set's 4D cube far
//! more evenly than independent ones: any prefix of `2^k` points has one point in every
//! elementary interval of the Sobol structure. Renders put the pixel jitter and the
//! environment's 2D sample in the first set, so both are stratified together.
//!
//! Like [`super::rng::SampleRng`], every value is a pure function of
//! `(seed, pixel, sample, dimension)`. Sequences hold `2^16` points; samples past that take
//! the next block of `2^16`, scrambled independently (an independent replicate).
//!
//! One consequence for statistics: the samples of a pixel are negatively correlated, so
//! the sample variance over `n` overestimates the variance of their mean (a conservative
//! standard error).

use super::rng::{hash4, mix64, Sampler};

/// Domain separation from the other users of [`hash4`].
const SOBOL_DOMAIN: u64 = 0x50b0_1d15_ea5e_0001;

/// Domain of the light draws' stream ([`PixelSampler::light_draw`]).
const DRAW_DOMAIN: u64 = 0x50b0_1d15_ea5e_0002;

/// The quasi-random stream of one sample of one pixel: `get(d)` is dimension `d`, and the
/// dimensions `4k..4k+4` of a pixel's samples form one scrambled 4D Sobol sequence.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelSampler {
    /// What the sampler was made from: `(seed, pixel, sample)`.
    origin: (u64, u64, u64),
    /// Scramble of the pixel and block.
    key: u64,
    /// Index within the block of `2^16`.
    index: u32,
    /// Set 0, which every sample reads (twice: the pixel jitter and the environment).
    first: [f32; 4],
}

impl PixelSampler {
    /// Sample `sample` of pixel `pixel` under `seed`.
    pub fn new(seed: u64, pixel: u64, sample: u64) -> Self {
        Self::in_domain(seed, pixel, sample, SOBOL_DOMAIN)
    }

    fn in_domain(seed: u64, pixel: u64, sample: u64, domain: u64) -> Self {
        let key = hash4(seed, pixel, sample >> 16, domain);
        let index = (sample & 0xffff) as u32;
        let mut first = Self::set(key, index, 0);
        if domain == DRAW_DOMAIN {
            // A draw reads no pixel jitter: its environment pair (dimensions 2-3) takes
            // Sobol's first two dimensions, the pair that is a (0, 2)-sequence.
            first = [first[2], first[3], first[0], first[1]];
        }
        Self {
            origin: (seed, pixel, sample),
            key,
            index,
            first,
        }
    }

    /// Light draw `j` of `n` of this sample: point `sample · n + j` of the pixel's second
    /// stream (scrambled independently of the first), so the `n` draws of one sample are
    /// consecutive points of one Sobol sequence (for `n` a power of two, an aligned block
    /// that fills the unit square's strata evenly) and the draws of all the pixel's
    /// samples together are its first `spp · n` points. Every draw is uniform on its own.
    pub fn light_draw(&self, j: u32, n: u32) -> Self {
        debug_assert!(j < n);
        let (seed, pixel, sample) = self.origin;
        Self::in_domain(seed, pixel, sample * n as u64 + j as u64, DRAW_DOMAIN)
    }

    /// Dimensions `4 set .. 4 set + 4`.
    #[inline]
    pub fn get4(&self, set: u64) -> [f32; 4] {
        if set == 0 {
            self.first
        } else {
            Self::set(self.key, self.index, set)
        }
    }

    #[inline]
    fn set(key: u64, index: u32, set: u64) -> [f32; 4] {
        let seed = mix64(key ^ set.wrapping_mul(0x9e37_79b9_7f4a_7c15)) as u32;
        sobol_burley::sample_4d(index, 0, seed)
    }
}

impl Sampler for PixelSampler {
    #[inline]
    fn get(&self, d: u64) -> f32 {
        self.get4(d >> 2)[(d & 3) as usize]
    }

    /// A stratified pair when `d` is `4k` or `4k + 2` (dimensions of one set).
    #[inline]
    fn get2(&self, d: u64) -> [f32; 2] {
        let lane = (d & 3) as usize;
        debug_assert!(
            lane != 3,
            "a pair must lie within one set of four dimensions"
        );
        let v = self.get4(d >> 2);
        [v[lane], v[(lane + 1).min(3)]]
    }

    #[inline]
    fn get_set(&self, d: u64) -> [f32; 4] {
        debug_assert!(d.is_multiple_of(4), "a set starts at a multiple of four");
        self.get4(d >> 2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pure_function_of_its_inputs_in_the_unit_interval() {
        let a = PixelSampler::new(3, 10, 2);
        assert_eq!(a.get(5), PixelSampler::new(3, 10, 2).get(5));
        assert_ne!(a.get(5), PixelSampler::new(4, 10, 2).get(5));
        assert_ne!(a.get(5), PixelSampler::new(3, 11, 2).get(5));
        for s in 0..1000 {
            for d in 0..16 {
                let v = PixelSampler::new(1, 7, s).get(d);
                assert!((0.0..1.0).contains(&v));
            }
        }
    }

    #[test]
    fn a_pixels_samples_are_stratified_in_each_pair() {
        // The first 2^8 samples of a pixel put exactly one point in each cell of a 16 x 16
        // grid over every pair (a (0, 2)-sequence property of Sobol dimensions 0-1 that
        // the scramble keeps), and exactly 16 in each row of the other pair.
        for pixel in 0..20 {
            let mut grid = [0u32; 256];
            let mut rows = [0u32; 16];
            for s in 0..256 {
                let p = PixelSampler::new(9, pixel, s);
                let [x, y] = p.get2(0);
                grid[(y * 16.0) as usize * 16 + (x * 16.0) as usize] += 1;
                rows[(p.get(2) * 16.0) as usize] += 1;
            }
            assert!(grid.iter().all(|&c| c == 1), "pixel {pixel}");
            assert!(rows.iter().all(|&c| c == 16), "pixel {pixel}");
        }
    }

    #[test]
    fn every_sample_is_uniform_over_pixels() {
        // One sample per pixel over many pixels: independent uniform values (scrambles
        // differ per pixel), tested by a chi-square over 64 bins of each of 8 dimensions.
        let n = 64_000u64;
        for d in 0..8 {
            for s in [0u64, 5, 70_000] {
                let mut counts = [0u32; 64];
                for pixel in 0..n {
                    counts[(PixelSampler::new(2, pixel, s).get(d) * 64.0) as usize] += 1;
                }
                let e = n as f64 / 64.0;
                let chi2: f64 = counts.iter().map(|&c| (c as f64 - e).powi(2) / e).sum();
                // 63 degrees of freedom: mean + 5 standard deviations.
                assert!(chi2 < 63.0 + 5.0 * (126.0f64).sqrt(), "d {d} s {s}: {chi2}");
            }
        }
    }

    #[test]
    fn blocks_past_the_sequence_length_are_new_scrambles() {
        let a = PixelSampler::new(1, 2, 3);
        let b = PixelSampler::new(1, 2, 3 + (1 << 16));
        assert_ne!(a.get4(0), b.get4(0));
    }

    #[test]
    fn light_draws_are_stratified_within_a_sample_and_over_the_pixel() {
        // 4 draws of each of 64 samples: the 4 draws of one sample put one point in each
        // quarter of the env pair's square (2 x 2), and all 256 draws of the pixel one
        // point in each cell of a 16 x 16 grid; the draws' stream is not the samples'.
        let env = 2;
        for pixel in 0..20 {
            let mut grid = [0u32; 256];
            for s in 0..64 {
                let sample = PixelSampler::new(4, pixel, s);
                let mut quarters = [0u32; 4];
                for j in 0..4 {
                    let [x, y] = sample.light_draw(j, 4).get2(env);
                    quarters[(y * 2.0) as usize * 2 + (x * 2.0) as usize] += 1;
                    grid[(y * 16.0) as usize * 16 + (x * 16.0) as usize] += 1;
                }
                assert_eq!(quarters, [1; 4], "pixel {pixel} sample {s}");
                assert_ne!(sample.light_draw(0, 1).get2(env), sample.get2(env));
            }
            assert!(grid.iter().all(|&c| c == 1), "pixel {pixel}");
        }
    }
}
