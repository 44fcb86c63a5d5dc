//! `Σ weights[i]` over the set bits `i` of one 64-bit word of a record: the integral of
//! `L B~` over the visible texels of a partial word (CAM08 §5.5), branch-free.
//!
//! Every form adds in the same order — lane `j` of eight sums `weights[8k + j]` for
//! `k = 0..8` in turn, then the lanes pair up as `((0+4)+(2+6)) + ((1+5)+(3+7))` — so the
//! AVX-512, AVX2 and portable kernels return the same bits on every CPU. Adding `+0.0` for
//! a clear bit (AVX2, portable) equals not adding (AVX-512's masked add): the weights and
//! partial sums are `>= +0`.

/// The sum in the documented order, portable form.
#[inline(always)]
pub(super) fn masked_sum_portable(bits: u64, weights: &[f64; 64]) -> f64 {
    let mut acc = [0.0f64; 8];
    for k in 0..8 {
        let byte = (bits >> (8 * k)) as u32;
        for (j, a) in acc.iter_mut().enumerate() {
            *a += if byte >> j & 1 != 0 {
                weights[8 * k + j]
            } else {
                0.0
            };
        }
    }
    ((acc[0] + acc[4]) + (acc[2] + acc[6])) + ((acc[1] + acc[5]) + (acc[3] + acc[7]))
}

/// AVX-512: one masked add of eight weights per byte of `bits`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub(super) fn masked_sum_avx512(bits: u64, weights: &[f64; 64]) -> f64 {
    use std::arch::x86_64::*;
    let mut acc = _mm512_setzero_pd();
    for k in 0..8 {
        // SAFETY: `8k + 8 <= 64` weights; unaligned load.
        let w = unsafe { _mm512_loadu_pd(weights.as_ptr().add(8 * k)) };
        acc = _mm512_mask_add_pd(acc, (bits >> (8 * k)) as u8, acc, w);
    }
    let halves = _mm256_add_pd(
        _mm512_castpd512_pd256(acc),
        _mm512_extractf64x4_pd::<1>(acc),
    );
    reduce_pairs(halves)
}

/// AVX2: lanes 0–3 and 4–7 as two accumulators, a nibble of `bits` masking each load.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn masked_sum_avx2(bits: u64, weights: &[f64; 64]) -> f64 {
    use std::arch::x86_64::*;
    let low = _mm256_setr_epi64x(1, 2, 4, 8);
    let high = _mm256_setr_epi64x(16, 32, 64, 128);
    let (mut acc_low, mut acc_high) = (_mm256_setzero_pd(), _mm256_setzero_pd());
    for k in 0..8 {
        let byte = _mm256_set1_epi64x(((bits >> (8 * k)) & 0xff) as i64);
        let mask_low = _mm256_cmpeq_epi64(_mm256_and_si256(byte, low), low);
        let mask_high = _mm256_cmpeq_epi64(_mm256_and_si256(byte, high), high);
        // SAFETY: `8k + 8 <= 64` weights; unaligned loads.
        let (w_low, w_high) = unsafe {
            (
                _mm256_loadu_pd(weights.as_ptr().add(8 * k)),
                _mm256_loadu_pd(weights.as_ptr().add(8 * k + 4)),
            )
        };
        acc_low = _mm256_add_pd(acc_low, _mm256_and_pd(w_low, _mm256_castsi256_pd(mask_low)));
        acc_high = _mm256_add_pd(
            acc_high,
            _mm256_and_pd(w_high, _mm256_castsi256_pd(mask_high)),
        );
    }
    reduce_pairs(_mm256_add_pd(acc_low, acc_high))
}

/// `(h0 + h2) + (h1 + h3)` of `halves = [a0+a4, a1+a5, a2+a6, a3+a7]`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
fn reduce_pairs(halves: std::arch::x86_64::__m256d) -> f64 {
    use std::arch::x86_64::*;
    let pairs = _mm_add_pd(
        _mm256_castpd256_pd128(halves),
        _mm256_extractf128_pd::<1>(halves),
    );
    _mm_cvtsd_f64(_mm_add_sd(pairs, _mm_unpackhi_pd(pairs, pairs)))
}

/// The sum with the best kernel this CPU has (detected once; one call per word, for
/// callers off the hot path).
pub(super) fn masked_sum(bits: u64, weights: &[f64; 64]) -> f64 {
    #[cfg(target_arch = "x86_64")]
    {
        use crate::simd::{level, SimdLevel};
        match level() {
            // SAFETY (both): the CPU has the features, detected by `crate::simd`.
            SimdLevel::Avx512 => return unsafe { masked_sum_avx512(bits, weights) },
            SimdLevel::Avx2 => return unsafe { masked_sum_avx2(bits, weights) },
            _ => {}
        }
    }
    masked_sum_portable(bits, weights)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::{hash4, to_unit_f64};

    #[test]
    fn every_masked_sum_kernel_agrees_bit_for_bit_with_the_portable_sum() {
        for case in 0..2000u64 {
            // Weights over many magnitudes, so that any other order would round
            // differently; bits from empty through single bits to full.
            let weights: [f64; 64] = std::array::from_fn(|i| {
                let u = to_unit_f64(hash4(7, case, i as u64, 0));
                let e = (hash4(7, case, i as u64, 1) % 40) as i32 - 20;
                u * 2f64.powi(e)
            });
            let bits = match case {
                0 => 0,
                1 => u64::MAX,
                2..=65 => 1u64 << (case - 2),
                _ => hash4(8, case, 0, 0) & hash4(8, case, 1, 0).rotate_left(case as u32),
            };
            let expected = masked_sum_portable(bits, &weights);
            let plain: f64 = (0..64)
                .filter(|i| bits >> i & 1 == 1)
                .map(|i| weights[i])
                .sum();
            assert!(
                (expected - plain).abs() <= 1e-13 * plain,
                "{expected} vs {plain}"
            );
            assert_eq!(masked_sum(bits, &weights).to_bits(), expected.to_bits());
            #[cfg(target_arch = "x86_64")]
            {
                use std::arch::is_x86_feature_detected as has;
                // SAFETY (both): the features were detected just before.
                if has!("avx512f") {
                    let got = unsafe { masked_sum_avx512(bits, &weights) };
                    assert_eq!(got.to_bits(), expected.to_bits(), "AVX-512, case {case}");
                }
                if has!("avx2") {
                    let got = unsafe { masked_sum_avx2(bits, &weights) };
                    assert_eq!(got.to_bits(), expected.to_bits(), "AVX2, case {case}");
                }
            }
        }
    }
}
