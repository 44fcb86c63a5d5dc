//! The inner loops of a lighting change: one pixel's transfer row against the map's
//! projection. They are most of a change's time (for each of 307,200 pixels at 640x480,
//! 154–219 Haar terms or 64 dense ones), so each carries AVX2 and AVX-512 forms, chosen
//! by [`crate::simd::dispatch`]. Both sum in independent partial sums so that the
//! additions do not wait on each other, and every form adds the same products in the
//! same order: the same sums bit for bit.
//!
//! - [`haar_sums`]: the kept terms of a Haar row (a coefficient index and a quantised
//!   value each) against the light's coefficients in `f32`, term `k` of each group of four
//!   into partial sum `k`. The vector forms put the four sums side by side in one
//!   register, which the compiler did not find (it split each `[f32; 4]` into halves,
//!   with a bounds check per term: twice the time).
//! - [`dense_sums`]: a dense row (texel or SH coefficients, `f32`) against the light in
//!   `f64`, one run per channel, term `k` into lane `k mod 8` of its channel. Left to the
//!   compiler, the loop over `[f64; 4]` lanes was masked and permuted, and fixed-size
//!   arrays of eight became copies.

use crate::simd::{Kernel, Level, SimdLevel};

/// A Haar word's coefficient index and quantised value: index in the high 16 bits, the
/// value as an `i16` in the low ones.
#[inline(always)]
pub fn unpack(w: u32) -> (usize, i16) {
    ((w >> 16) as usize, w as u16 as i16)
}

/// The four partial sums of `Σ v_k l[i_k]` over the Haar `terms` ([`unpack`]): term `k` of each
/// group of four adds to sum `k`, a last partial group to the first sums. Lane 3 of `light`
/// rides along (zero for RGB). `light.len()` must be a power of two (4^level); an index
/// past it wraps, so that no form reads outside `light`.
pub fn haar_sums(terms: &[u32], light: &[[f32; 4]]) -> [[f32; 4]; 4] {
    assert!(
        light.len().is_power_of_two(),
        "a Haar light has 4^level coefficients"
    );
    crate::simd::dispatch(HaarSums { terms, light })
}

/// [`haar_sums`] at a chosen instruction set (None when this CPU lacks it): the tests
/// hold each form to the portable one.
pub fn haar_sums_at(at: SimdLevel, terms: &[u32], light: &[[f32; 4]]) -> Option<[[f32; 4]; 4]> {
    assert!(light.len().is_power_of_two());
    crate::simd::run_at(at, HaarSums { terms, light })
}

struct HaarSums<'a> {
    terms: &'a [u32],
    light: &'a [[f32; 4]],
}

impl Kernel for HaarSums<'_> {
    type Output = [[f32; 4]; 4];

    #[inline(always)]
    fn run<L: Level>(self, _level: L) -> Self::Output {
        let Self { terms, light } = self;
        let mut sums = [[0.0f32; 4]; 4];
        let whole = terms.len() / 4 * 4;
        match L::LEVEL {
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here AVX-512 F and VL.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => unsafe { groups_avx512(&terms[..whole], light, &mut sums) },
            // SAFETY: as above, AVX2.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx2 => unsafe { groups_avx2(&terms[..whole], light, &mut sums) },
            _ => groups_portable(&terms[..whole], light, &mut sums),
        }
        groups_portable(&terms[whole..], light, &mut sums);
        sums
    }
}

/// Adds the terms to `sums`, term `k` of each group of four to sum `k`.
#[inline(always)]
fn groups_portable(terms: &[u32], light: &[[f32; 4]], sums: &mut [[f32; 4]; 4]) {
    let mask = light.len() - 1;
    for group in terms.chunks(4) {
        for (sum, &w) in sums.iter_mut().zip(group) {
            let (index, value) = unpack(w);
            let l = &light[index & mask];
            let v = value as f32;
            for c in 0..4 {
                sum[c] += v * l[c];
            }
        }
    }
}

/// [`groups_portable`] over whole groups with the four sums in one 512-bit register.
///
/// # Safety
/// The CPU has AVX-512 F; `terms.len()` is a multiple of 4; `light.len()` a power of two.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn groups_avx512(terms: &[u32], light: &[[f32; 4]], sums: &mut [[f32; 4]; 4]) {
    use std::arch::x86_64::*;
    let mask = light.len() - 1;
    let base = light.as_ptr() as *const f32;
    // Each term's value across its sum's four lanes.
    let spread = _mm512_set_epi32(3, 3, 3, 3, 2, 2, 2, 2, 1, 1, 1, 1, 0, 0, 0, 0);
    let mut acc = _mm512_loadu_ps(sums.as_ptr() as *const f32);
    for g in terms.chunks_exact(4) {
        let words = _mm_loadu_si128(g.as_ptr() as *const __m128i);
        let values = _mm_cvtepi32_ps(_mm_srai_epi32::<16>(_mm_slli_epi32::<16>(words)));
        let values = _mm512_permutexvar_ps(spread, _mm512_castps128_ps512(values));
        // SAFETY: every index is masked into `light`.
        let at = |w: u32| _mm_loadu_ps(base.add(4 * (unpack(w).0 & mask)));
        let l = _mm512_castps128_ps512(at(g[0]));
        let l = _mm512_insertf32x4::<1>(l, at(g[1]));
        let l = _mm512_insertf32x4::<2>(l, at(g[2]));
        let l = _mm512_insertf32x4::<3>(l, at(g[3]));
        acc = _mm512_add_ps(acc, _mm512_mul_ps(values, l));
    }
    _mm512_storeu_ps(sums.as_mut_ptr() as *mut f32, acc);
}

/// [`groups_portable`] over whole groups with sums 0 and 1 in one 256-bit register and
/// sums 2 and 3 in another.
///
/// # Safety
/// The CPU has AVX2; `terms.len()` is a multiple of 4; `light.len()` a power of two.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn groups_avx2(terms: &[u32], light: &[[f32; 4]], sums: &mut [[f32; 4]; 4]) {
    use std::arch::x86_64::*;
    let mask = light.len() - 1;
    let base = light.as_ptr() as *const f32;
    let first = _mm256_set_epi32(1, 1, 1, 1, 0, 0, 0, 0);
    let second = _mm256_set_epi32(3, 3, 3, 3, 2, 2, 2, 2);
    let out = sums.as_mut_ptr() as *mut f32;
    let (mut low, mut high) = (_mm256_loadu_ps(out), _mm256_loadu_ps(out.add(8)));
    for g in terms.chunks_exact(4) {
        let words = _mm_loadu_si128(g.as_ptr() as *const __m128i);
        let values = _mm_cvtepi32_ps(_mm_srai_epi32::<16>(_mm_slli_epi32::<16>(words)));
        let values = _mm256_castps128_ps256(values);
        // SAFETY: every index is masked into `light`.
        let at = |w: u32| base.add(4 * (unpack(w).0 & mask));
        let l01 = _mm256_loadu2_m128(at(g[1]), at(g[0]));
        let l23 = _mm256_loadu2_m128(at(g[3]), at(g[2]));
        low = _mm256_add_ps(
            low,
            _mm256_mul_ps(_mm256_permutevar8x32_ps(values, first), l01),
        );
        high = _mm256_add_ps(
            high,
            _mm256_mul_ps(_mm256_permutevar8x32_ps(values, second), l23),
        );
    }
    _mm256_storeu_ps(out, low);
    _mm256_storeu_ps(out.add(8), high);
}

/// Lanes of [`dense_sums`]' partial sums: one 512-bit register of `f64`.
const DENSE_LANES: usize = 8;

/// `Σ w_k l_c[k]` per channel `c` over a dense row (`f32` bits) and the light (one run of
/// `f64` per channel, `light[c]`), over the shortest of them: term `k` adds to partial sum
/// `k mod 8` of its channel, and the eight are added pairwise in a fixed order.
pub fn dense_sums(words: &[u32], light: [&[f64]; 3]) -> [f64; 3] {
    crate::simd::dispatch(DenseSums { words, light })
}

/// [`dense_sums`] at a chosen instruction set (None when this CPU lacks it).
pub fn dense_sums_at(at: SimdLevel, words: &[u32], light: [&[f64]; 3]) -> Option<[f64; 3]> {
    crate::simd::run_at(at, DenseSums { words, light })
}

struct DenseSums<'a> {
    words: &'a [u32],
    light: [&'a [f64]; 3],
}

impl Kernel for DenseSums<'_> {
    type Output = [f64; 3];

    #[inline(always)]
    fn run<L: Level>(self, _level: L) -> Self::Output {
        let n = self
            .light
            .iter()
            .fold(self.words.len(), |n, l| n.min(l.len()));
        let words = &self.words[..n];
        let light = self.light.map(|l| &l[..n]);
        let mut sums = [[0.0f64; DENSE_LANES]; 3];
        let whole = n / DENSE_LANES * DENSE_LANES;
        match L::LEVEL {
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here AVX-512 F.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => unsafe { lanes_avx512(&words[..whole], light, &mut sums) },
            // SAFETY: as above, AVX2.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx2 => unsafe { lanes_avx2(&words[..whole], light, &mut sums) },
            _ => lanes_portable(&words[..whole], light, 0, &mut sums),
        }
        lanes_portable(&words[whole..], light, whole, &mut sums);
        sums.map(|s| ((s[0] + s[4]) + (s[2] + s[6])) + ((s[1] + s[5]) + (s[3] + s[7])))
    }
}

/// Adds `w_k l_c[from + k]` to lane `k mod 8` of channel `c`'s sums (`from` a multiple of
/// 8).
#[inline(always)]
fn lanes_portable(
    words: &[u32],
    light: [&[f64]; 3],
    from: usize,
    sums: &mut [[f64; DENSE_LANES]; 3],
) {
    for (k, &w) in words.iter().enumerate() {
        let v = f32::from_bits(w) as f64;
        for (sum, l) in sums.iter_mut().zip(light) {
            sum[k % DENSE_LANES] += v * l[from + k];
        }
    }
}

/// [`lanes_portable`] from 0 over whole groups of eight, a channel's sums in one 512-bit
/// register.
///
/// # Safety
/// The CPU has AVX-512 F; `words.len()` is a multiple of 8 and at most each `light[c]`'s.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn lanes_avx512(words: &[u32], light: [&[f64]; 3], sums: &mut [[f64; DENSE_LANES]; 3]) {
    use std::arch::x86_64::*;
    let mut acc = sums.map(|s| _mm512_loadu_pd(s.as_ptr()));
    for at in (0..words.len()).step_by(DENSE_LANES) {
        let v = _mm512_cvtps_pd(_mm256_loadu_ps(words.as_ptr().add(at) as *const f32));
        for (a, l) in acc.iter_mut().zip(light) {
            *a = _mm512_add_pd(*a, _mm512_mul_pd(v, _mm512_loadu_pd(l.as_ptr().add(at))));
        }
    }
    for (s, a) in sums.iter_mut().zip(acc) {
        _mm512_storeu_pd(s.as_mut_ptr(), a);
    }
}

/// [`lanes_portable`] from 0 over whole groups of eight, a channel's sums in two 256-bit
/// registers.
///
/// # Safety
/// The CPU has AVX2; `words.len()` is a multiple of 8 and at most each `light[c]`'s.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn lanes_avx2(words: &[u32], light: [&[f64]; 3], sums: &mut [[f64; DENSE_LANES]; 3]) {
    use std::arch::x86_64::*;
    let mut low = sums.map(|s| _mm256_loadu_pd(s.as_ptr()));
    let mut high = sums.map(|s| _mm256_loadu_pd(s.as_ptr().add(4)));
    for at in (0..words.len()).step_by(DENSE_LANES) {
        let w = _mm256_loadu_ps(words.as_ptr().add(at) as *const f32);
        let v_low = _mm256_cvtps_pd(_mm256_castps256_ps128(w));
        let v_high = _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(w));
        for c in 0..3 {
            let l = light[c].as_ptr().add(at);
            low[c] = _mm256_add_pd(low[c], _mm256_mul_pd(v_low, _mm256_loadu_pd(l)));
            high[c] = _mm256_add_pd(high[c], _mm256_mul_pd(v_high, _mm256_loadu_pd(l.add(4))));
        }
    }
    for c in 0..3 {
        _mm256_storeu_pd(sums[c].as_mut_ptr(), low[c]);
        _mm256_storeu_pd(sums[c].as_mut_ptr().add(4), high[c]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_form_gives_the_portable_sums_bit_for_bit() {
        let rng = crate::sampling::rng::SampleRng::new(11, 0, 0);
        let mut d = 0;
        let mut uniform = || {
            d += 1;
            rng.get(d)
        };
        let light: Vec<[f32; 4]> = (0..256)
            .map(|_| [0, 1, 2].map(|_| (uniform() - 0.3) * 1e3))
            .map(|[r, g, b]| [r, g, b, 0.0])
            .collect();
        // Every remainder of four, indices past the light (wrapped), extreme values.
        for len in [0usize, 1, 3, 4, 5, 8, 153, 154, 219] {
            let terms: Vec<u32> = (0..len)
                .map(|k| {
                    let index = (uniform() * 300.0) as u16;
                    let value = match k % 7 {
                        0 => i16::MAX,
                        1 => i16::MIN,
                        2 => 0,
                        _ => (uniform() * 65536.0) as u16 as i16,
                    };
                    ((index as u32) << 16) | value as u16 as u32
                })
                .collect();
            let portable = haar_sums_at(SimdLevel::Portable, &terms, &light).unwrap();
            // Against a plain loop.
            let mut plain = [[0.0f32; 4]; 4];
            for (k, &w) in terms.iter().enumerate() {
                let (index, value) = unpack(w);
                for c in 0..4 {
                    plain[k % 4][c] += value as f32 * light[index % 256][c];
                }
            }
            assert_eq!(portable, plain, "{len} terms");
            for at in [SimdLevel::Avx2, SimdLevel::Avx512] {
                if let Some(sums) = haar_sums_at(at, &terms, &light) {
                    let bits = |s: [[f32; 4]; 4]| s.map(|r| r.map(f32::to_bits));
                    assert_eq!(bits(sums), bits(portable), "{} with {len} terms", at.name());
                }
            }
        }
    }

    #[test]
    fn dense_forms_agree_bit_for_bit_and_with_a_plain_sum() {
        let rng = crate::sampling::rng::SampleRng::new(12, 0, 0);
        let light: [Vec<f64>; 3] = std::array::from_fn(|c| {
            (0..64u64)
                .map(|k| (rng.get(3 * k + c as u64) as f64 - 0.4) * 1e4)
                .collect()
        });
        let light = [&light[0][..], &light[1][..], &light[2][..]];
        for len in [0usize, 1, 3, 4, 7, 8, 9, 16, 63, 64, 80] {
            let words: Vec<u32> = (0..len as u64)
                .map(|k| ((rng.get(1000 + k) - 0.5) * 3.0).to_bits())
                .collect();
            let portable = dense_sums_at(SimdLevel::Portable, &words, light).unwrap();
            let plain: [f64; 3] = std::array::from_fn(|c| {
                words
                    .iter()
                    .zip(light[c])
                    .map(|(&w, l)| f32::from_bits(w) as f64 * l)
                    .sum()
            });
            for c in 0..3 {
                assert!((portable[c] - plain[c]).abs() <= 1e-9 * (1.0 + plain[c].abs()));
            }
            for at in [SimdLevel::Avx2, SimdLevel::Avx512] {
                if let Some(sums) = dense_sums_at(at, &words, light) {
                    let bits = |s: [f64; 3]| s.map(f64::to_bits);
                    assert_eq!(bits(sums), bits(portable), "{} with {len} terms", at.name());
                }
            }
        }
    }
}
