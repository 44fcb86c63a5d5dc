//! The candidates of one lookup keyed by squared distance, then id, as one integer, and
//! the selection of the `m` least of them.

/// The candidates of one lookup: their [`candidate_key`]s (distinct: ids differ) and their
/// indices into [`Passed`].
#[derive(Clone, Debug, Default)]
pub(super) struct Candidates {
    key: Vec<u64>,
    passed: Vec<u32>,
    /// Working space of the portable selection.
    selection: Vec<u64>,
}

impl Candidates {
    pub(super) fn clear(&mut self) {
        self.key.clear();
        self.passed.clear();
    }

    #[inline]
    pub(super) fn push(&mut self, key: u64, passed: u32) {
        self.key.push(key);
        self.passed.push(passed);
    }

    /// Calls `f(key, passed index)` for the `m` candidates of least key (all of them when
    /// there are no more than `m`), in the order they were pushed.
    #[inline]
    pub(super) fn for_each_least(&mut self, m: usize, mut f: impl FnMut(u64, u32)) {
        let count = self.key.len();
        if count <= m {
            for (&key, &passed) in self.key.iter().zip(&self.passed) {
                f(key, passed);
            }
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if count <= 32 {
            let keys = &self.key;
            if let Some(mut least) = crate::simd::dispatch_avx512_detected(LeastByRank { keys, m })
            {
                while least != 0 {
                    let i = least.trailing_zeros() as usize;
                    least &= least - 1;
                    f(self.key[i], self.passed[i]);
                }
                return;
            }
        }
        let bound = self.mth_least(m);
        for (&key, &passed) in self.key.iter().zip(&self.passed) {
            if key <= bound {
                f(key, passed);
            }
        }
    }

    /// The `m`-th least key (`1 <= m < len`).
    fn mth_least(&mut self, m: usize) -> u64 {
        self.selection.clear();
        self.selection.extend_from_slice(&self.key);
        *self.selection.select_nth_unstable(m - 1).1
    }
}

/// [`least_by_rank_avx512`] as a [`Kernel`](crate::simd::Kernel) (`m < keys.len() <= 32`):
/// `None` without AVX-512. The AVX-512 form is never inlined into the dispatcher's
/// function, whose feature set differs (AVX-512 VL): it stays compiled exactly for its own
/// set.
#[cfg(target_arch = "x86_64")]
struct LeastByRank<'a> {
    keys: &'a [u64],
    m: usize,
}

#[cfg(target_arch = "x86_64")]
impl crate::simd::Kernel for LeastByRank<'_> {
    type Output = Option<u32>;

    #[inline(always)]
    fn run<L: crate::simd::Level>(self, _level: L) -> Option<u32> {
        match L::LEVEL {
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here AVX-512 F; `m < keys.len() <= 32`.
            crate::simd::SimdLevel::Avx512 => unsafe { least_by_rank_avx512(self.keys, self.m) },
            _ => None,
        }
    }
}

/// Bit `i` set for the `m` least of `keys` (`m < keys.len() <= 32`), by ranks counted
/// sixteen lanes at a time on the upper halves of the keys (the squared distances' bits).
/// Records at equal distances rank alike there, so when they straddle the m-th place the
/// answer is left to the exact selection (`None`).
///
/// # Safety
/// The CPU must have AVX-512 F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline(never)]
unsafe fn least_by_rank_avx512(keys: &[u64], m: usize) -> Option<u32> {
    use std::arch::x86_64::*;
    let count = keys.len();
    debug_assert!(m < count && count <= 32);
    let mut upper = [u32::MAX; 32];
    for (u, &k) in upper.iter_mut().zip(keys) {
        *u = (k >> 32) as u32;
    }
    // SAFETY: `upper` holds 32 u32s.
    let (low, high) = unsafe {
        (
            _mm512_loadu_si512(upper.as_ptr().cast()),
            _mm512_loadu_si512(upper.as_ptr().add(16).cast()),
        )
    };
    // Rank of each key: how many keys lie strictly below it (padding, at u32::MAX, lies
    // below none and ranks `count`, past every place kept).
    let one = _mm512_set1_epi32(1);
    let (mut rank_low, mut rank_high) = (_mm512_setzero_si512(), _mm512_setzero_si512());
    for &u in &upper[..count] {
        let u = _mm512_set1_epi32(u as i32);
        rank_low = _mm512_mask_add_epi32(rank_low, _mm512_cmplt_epu32_mask(u, low), rank_low, one);
        rank_high =
            _mm512_mask_add_epi32(rank_high, _mm512_cmplt_epu32_mask(u, high), rank_high, one);
    }
    let places = _mm512_set1_epi32(m as i32);
    let least = _mm512_cmplt_epu32_mask(rank_low, places) as u32
        | (_mm512_cmplt_epu32_mask(rank_high, places) as u32) << 16;
    // More than m ranked below m: equal distances tie across the m-th place.
    (least.count_ones() as usize == m).then_some(least)
}

/// Orders candidates by their metric's value ([`super::Metric::key`]: squared distance
/// by default), then record id, as one integer: the value is finite and non-negative, so
/// its bits order as it does.
#[inline]
pub(super) fn candidate_key(d2: f32, id: u32) -> u64 {
    ((d2.to_bits() as u64) << 32) | id as u64
}

/// The metric's value of a [`candidate_key`].
#[cfg(test)]
#[inline]
pub(super) fn key_d2(key: u64) -> f32 {
    f32::from_bits((key >> 32) as u32)
}

/// The record id of a [`candidate_key`].
#[inline]
pub(super) fn key_id(key: u64) -> u32 {
    key as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::{hash4, to_unit_f32};

    fn unit(seed: u64, k: u64) -> f32 {
        to_unit_f32(hash4(seed, k, 0, 5))
    }

    /// The m least candidates come out in push order, by every path (ranks under AVX-512,
    /// the exact selection past 32 candidates or on ties across the m-th place), as a
    /// sort gives them, with many distances shared.
    #[test]
    fn the_least_candidates_are_those_a_sort_keeps() {
        let mut candidates = Candidates::default();
        let mut by_rank = 0;
        for case in 0..600u64 {
            let count = (case % 45) as usize;
            let m = 1 + (case / 45 % 17) as usize;
            let levels = [3.0, 40.0, 1e6][case as usize % 3];
            candidates.clear();
            let mut pushed = Vec::new();
            for k in 0..count as u64 {
                let d2 = (unit(case, k) * levels).floor() / levels;
                let key = candidate_key(d2, (hash4(case, k, 1, 2) % 1000) as u32 * 64 + k as u32);
                candidates.push(key, 7 * k as u32);
                pushed.push((key, 7 * k as u32));
            }
            let mut sorted: Vec<u64> = pushed.iter().map(|p| p.0).collect();
            sorted.sort_unstable();
            let expected: Vec<(u64, u32)> = pushed
                .iter()
                .copied()
                .filter(|p| sorted[..m.min(count)].contains(&p.0))
                .collect();
            let mut got = Vec::new();
            candidates.for_each_least(m, |key, j| got.push((key, j)));
            assert_eq!(got, expected, "case {case}: {count} candidates, m {m}");
            #[cfg(target_arch = "x86_64")]
            if m < count && count <= 32 && crate::simd::has(crate::simd::SimdLevel::Avx512) {
                // SAFETY: AVX-512 F detected.
                let least = unsafe { least_by_rank_avx512(&candidates.key, m) };
                let tied = sorted[m - 1] >> 32 == sorted[m] >> 32;
                assert_eq!(least.is_none(), tied, "case {case}");
                by_rank += least.is_some() as usize;
            }
        }
        #[cfg(target_arch = "x86_64")]
        if crate::simd::has(crate::simd::SimdLevel::Avx512) {
            assert!(by_rank > 100, "{by_rank} cases decided by rank");
        }
    }

    #[test]
    fn candidate_keys_order_by_distance_then_id() {
        let mut keys = [
            candidate_key(0.5, 7),
            candidate_key(0.0, 9),
            candidate_key(0.5, 3),
            candidate_key(1e-30, 1),
            candidate_key(2.0, 0),
        ];
        keys.sort_unstable();
        let decoded: Vec<(f32, u32)> = keys.iter().map(|&k| (key_d2(k), key_id(k))).collect();
        assert_eq!(
            decoded,
            vec![(0.0, 9), (1e-30, 1), (0.5, 3), (0.5, 7), (2.0, 0)]
        );
    }
}
