//! Scoring the `m` nearest records of a lookup: eq. 9's weight with Fig. 7's geometric
//! factor for each, one SIMD lane per record, and the choice of the `n` heaviest.

use super::candidates::key_id;
use super::weight::{normal_angle, raw_weight, Weighting};
use super::{MAX_KEEP, MAX_NEAREST};
use crate::simd::{Kernel, Level, SimdLevel};

/// The m nearest records of a query (no order) and what §5.1 scores them by, as structure
/// of arrays: [`Self::score`] runs one SIMD lane per record.
#[derive(Clone, Debug)]
pub(crate) struct Hits {
    /// Records held.
    pub(crate) len: usize,
    /// [`candidate_key`]s: the lookup's metric, then record id, as one integer.
    pub(super) key: [u64; HIT_LANES],
    /// Squared distance `|p_i − x|²` (the range query's summation order), `sin θ_i` as `|n × n_i|`,
    /// `cos θ_i` and `n · (p_i − x)`: the inputs of [`Self::score`].
    pub(super) d2: [f32; HIT_LANES],
    pub(super) sin: [f32; HIT_LANES],
    pub(super) cos: [f32; HIT_LANES],
    pub(super) along: [f32; HIT_LANES],
    /// Distance `d_i` (world units), `θ_i` (radians), `w_g` (Fig. 7) and the eq. 9 weight
    /// `w_i = w_g · ŵ(d_i, θ_i)`, filled by [`Self::score`].
    pub(crate) distance: [f32; HIT_LANES],
    pub(crate) theta: [f32; HIT_LANES],
    pub(crate) geometric: [f32; HIT_LANES],
    pub(crate) weight: [f32; HIT_LANES],
}

/// [`Hits::score`] as a [`Kernel`]: picks the form compiled for the dispatched instruction
/// set (the scalar loop, vectorised by the compiler for AVX2 or AVX-512 F).
struct ScoreKernel<'a> {
    hits: &'a mut Hits,
    d_max: f32,
    w_lo: f32,
    scale: f32,
    lambda: f32,
}

impl Kernel for ScoreKernel<'_> {
    type Output = ();

    #[inline(always)]
    fn run<L: Level>(self, _level: L) {
        let Self {
            hits,
            d_max,
            w_lo,
            scale,
            lambda,
        } = self;
        match L::LEVEL {
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here AVX-512 F.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => unsafe { hits.score_avx512(d_max, w_lo, scale, lambda) },
            // SAFETY: as above, AVX2.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx2 => unsafe { hits.score_avx2(d_max, w_lo, scale, lambda) },
            _ => hits.score_lanes(d_max, w_lo, scale, lambda),
        }
    }
}

/// Lanes of [`Hits`]: `m <= MAX_NEAREST`, scored 16 at a time.
pub(crate) const HIT_LANES: usize = MAX_NEAREST;

/// [`Hits::heaviest`] of up to 16 records as a [`Kernel`]: its AVX-512 form, else the
/// portable one. The AVX-512 form is never inlined into the dispatcher's function, whose
/// feature set differs (AVX-512 VL): it stays compiled exactly for its own set.
#[cfg(target_arch = "x86_64")]
struct HeaviestKernel<'a> {
    hits: &'a Hits,
    keep: usize,
    order: &'a mut [usize; MAX_KEEP],
}

#[cfg(target_arch = "x86_64")]
impl Kernel for HeaviestKernel<'_> {
    type Output = (usize, f32);

    #[inline(always)]
    fn run<L: Level>(self, _level: L) -> (usize, f32) {
        let Self { hits, keep, order } = self;
        match L::LEVEL {
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here AVX-512 F.
            SimdLevel::Avx512 => unsafe { hits.heaviest_avx512(keep, order) },
            _ => hits.heaviest_portable(keep, order),
        }
    }
}

impl Default for Hits {
    fn default() -> Self {
        // Lanes past `len` keep finite values: scoring runs over whole groups of 16.
        Self {
            len: 0,
            key: [0; HIT_LANES],
            d2: [1.0; HIT_LANES],
            sin: [0.0; HIT_LANES],
            cos: [1.0; HIT_LANES],
            along: [0.0; HIT_LANES],
            distance: [0.0; HIT_LANES],
            theta: [0.0; HIT_LANES],
            geometric: [0.0; HIT_LANES],
            weight: [0.0; HIT_LANES],
        }
    }
}

impl Hits {
    /// Record id of hit `i`.
    pub(crate) fn id(&self, i: usize) -> u32 {
        key_id(self.key[i])
    }

    /// The `keep` heaviest records held, heaviest first, into `order` (indices), and how
    /// many there are: ties go to the nearer record (under the lookup's metric), then the lower id, so the choice is
    /// deterministic. Weights of 0 carry nothing and are left out. Also the greatest
    /// weight (+0 when none is positive).
    pub(crate) fn heaviest(&self, keep: usize, order: &mut [usize; MAX_KEEP]) -> (usize, f32) {
        #[cfg(target_arch = "x86_64")]
        if self.len <= 16 {
            return crate::simd::dispatch_avx512(HeaviestKernel {
                hits: self,
                keep,
                order,
            });
        }
        self.heaviest_portable(keep, order)
    }

    /// [`Self::heaviest`] by one integer per record: the weight's bits (w >= 0 orders as
    /// its bits), then the complement of the nearer-first candidate key. Insertion into
    /// the few kept beats sorting all m.
    fn heaviest_portable(&self, keep: usize, order: &mut [usize; MAX_KEEP]) -> (usize, f32) {
        let mut keys = [0u128; MAX_KEEP];
        let mut len = 0;
        for i in 0..self.len {
            let w = self.weight[i];
            // Weights are in [0, 1]; zero and NaN carry nothing.
            if w <= 0.0 || w.is_nan() {
                continue;
            }
            let key = ((w.to_bits() as u128) << 64) | !self.key[i] as u128;
            if len == keep && key <= keys[keep - 1] {
                continue;
            }
            let mut at = len.min(keep - 1);
            while at > 0 && keys[at - 1] < key {
                keys[at] = keys[at - 1];
                order[at] = order[at - 1];
                at -= 1;
            }
            keys[at] = key;
            order[at] = i;
            len = (len + 1).min(keep);
        }
        let best = if len > 0 { self.weight[order[0]] } else { 0.0 };
        (len, best)
    }

    /// [`Self::heaviest`] for up to 16 records: `keep` rounds of a masked maximum over
    /// the weights in one register, the record of that weight (the least candidate key
    /// among equal ones) leaving the mask.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[inline(never)]
    fn heaviest_avx512(&self, keep: usize, order: &mut [usize; MAX_KEEP]) -> (usize, f32) {
        use std::arch::x86_64::*;
        debug_assert!(self.len <= 16);
        // SAFETY: `weight` holds at least 16 lanes.
        let w = unsafe { _mm512_loadu_ps(self.weight.as_ptr()) };
        let held = (1u32 << self.len).wrapping_sub(1) as u16;
        let mut active = _mm512_mask_cmp_ps_mask::<_CMP_GT_OQ>(held, w, _mm512_setzero_ps());
        let mut len = 0;
        let mut best = 0.0;
        while len < keep && active != 0 {
            let top = _mm512_mask_reduce_max_ps(active, w);
            if len == 0 {
                best = top;
            }
            let equal = _mm512_mask_cmp_ps_mask::<_CMP_EQ_OQ>(active, w, _mm512_set1_ps(top));
            let mut lane = equal.trailing_zeros() as usize;
            let mut rest = equal & (equal - 1);
            while rest != 0 {
                let other = rest.trailing_zeros() as usize;
                if self.key[other] < self.key[lane] {
                    lane = other;
                }
                rest &= rest - 1;
            }
            order[len] = lane;
            len += 1;
            active &= !(1u16 << lane);
        }
        (len, best)
    }

    /// Eq. 9 with `w_g` for every record held, from `d2`, `sin`, `cos` and `along`:
    /// `θ = atan2(sin, cos)`, `d = sqrt(d2)`, `ŵ = (w(d/d_max, θ) − w_lo)/(1 − w_lo)`
    /// clamped to `[0, 1]`, `w_g = sqrt(1 − min(|along| / d, 1))` (1 at `d = 0`). The same
    /// scalar operations per record as a loop would make, so every CPU gets the same bits;
    /// with AVX2 or AVX-512 the compiler runs the branch-free body in 8 or 16 lanes (lanes
    /// past `len` are computed and ignored; without them its cost model keeps it scalar).
    pub(crate) fn score(&mut self, weighting: &Weighting, d_max: f32) {
        let w_lo = weighting.w_lo;
        let scale = 1.0 / (1.0 - w_lo);
        let lambda = weighting.lambda;
        crate::simd::dispatch(ScoreKernel {
            hits: self,
            d_max,
            w_lo,
            scale,
            lambda,
        });
    }

    // The per-set forms are never inlined into the dispatcher's functions, whose feature
    // sets differ (AVX-512 VL): each stays compiled exactly for its own set.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[inline(never)]
    fn score_avx512(&mut self, d_max: f32, w_lo: f32, scale: f32, lambda: f32) {
        self.score_lanes(d_max, w_lo, scale, lambda);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline(never)]
    fn score_avx2(&mut self, d_max: f32, w_lo: f32, scale: f32, lambda: f32) {
        self.score_lanes(d_max, w_lo, scale, lambda);
    }

    /// [`Self::score`]'s loop, inlined into each form.
    #[inline(always)]
    fn score_lanes(&mut self, d_max: f32, w_lo: f32, scale: f32, lambda: f32) {
        let lanes = self.len.next_multiple_of(16).min(HIT_LANES);
        for i in 0..lanes {
            let theta = normal_angle(self.sin[i], self.cos[i]);
            let d = self.d2[i].sqrt();
            let w_hat = ((raw_weight(d / d_max, theta, lambda) - w_lo) * scale).clamp(0.0, 1.0);
            let w_g = if d > 0.0 {
                (1.0 - (self.along[i] / d).abs().min(1.0)).sqrt()
            } else {
                1.0
            };
            self.distance[i] = d;
            self.theta[i] = theta;
            self.geometric[i] = w_g;
            self.weight[i] = w_g * w_hat;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::{hash4, to_unit_f32};
    use crate::spatial::candidates::candidate_key;
    use crate::visibility::params::CacheParams;

    fn unit(seed: u64, k: u64) -> f32 {
        to_unit_f32(hash4(seed, k, 0, 7))
    }

    /// The weights of the m nearest come out the same bit for bit whichever vector form scores
    /// them, and equal the scalar formulas record by record.
    #[test]
    fn every_scoring_form_gives_the_scalar_weights() {
        let params = CacheParams::MEDIUM;
        let d_max = 0.3f32;
        for case in 0..200u64 {
            let mut hits = Hits {
                len: (case % (HIT_LANES as u64 + 1)) as usize,
                ..Hits::default()
            };
            for i in 0..HIT_LANES {
                let k = case * 1000 + i as u64;
                // Distances from 0 to past d_max, angles from 0 to θ_max, record offsets
                // anywhere from along the normal to in the tangent plane.
                let d = if i % 7 == 0 {
                    0.0
                } else {
                    1.1 * d_max * unit(21, k)
                };
                let theta = params.theta_max() * unit(22, k);
                hits.d2[i] = d * d;
                hits.sin[i] = theta.sin();
                hits.cos[i] = theta.cos();
                hits.along[i] = d * (2.0 * unit(23, k) - 1.0);
            }
            let mut reference = hits.clone();
            reference.score_lanes(
                d_max,
                params.weight_floor(),
                1.0 / (1.0 - params.weight_floor()),
                params.lambda_falloff,
            );
            let mut dispatched = hits.clone();
            dispatched.score(&params.weighting(), d_max);
            let lanes = hits.len.next_multiple_of(16).min(HIT_LANES);
            let bits = |h: &Hits| {
                let all = [h.distance, h.theta, h.geometric, h.weight];
                all.map(|a| a[..lanes].iter().map(|v| v.to_bits()).collect::<Vec<_>>())
            };
            assert_eq!(bits(&dispatched), bits(&reference), "case {case}");
            #[cfg(target_arch = "x86_64")]
            {
                use std::arch::is_x86_feature_detected as has;
                let (w_lo, lam) = (params.weight_floor(), params.lambda_falloff);
                let scale = 1.0 / (1.0 - w_lo);
                // SAFETY (both): the features were detected just before.
                if has!("avx512f") {
                    let mut h = hits.clone();
                    unsafe { h.score_avx512(d_max, w_lo, scale, lam) };
                    assert_eq!(bits(&h), bits(&reference), "AVX-512, case {case}");
                }
                if has!("avx2") {
                    let mut h = hits.clone();
                    unsafe { h.score_avx2(d_max, w_lo, scale, lam) };
                    assert_eq!(bits(&h), bits(&reference), "AVX2, case {case}");
                }
            }
            for i in 0..hits.len {
                let d = hits.d2[i].sqrt();
                let theta = normal_angle(hits.sin[i], hits.cos[i]);
                let w_hat = ((raw_weight(d / d_max, theta, params.lambda_falloff)
                    - params.weight_floor())
                    / (1.0 - params.weight_floor()))
                .clamp(0.0, 1.0);
                let w_g = if d > 0.0 {
                    (1.0 - (hits.along[i] / d).abs().min(1.0)).sqrt()
                } else {
                    1.0
                };
                assert_eq!(reference.distance[i], d);
                assert_eq!(reference.theta[i], theta);
                assert_eq!(reference.geometric[i], w_g);
                assert!(
                    (reference.weight[i] - w_g * w_hat).abs() <= 1e-6,
                    "case {case}, {i}"
                );
            }
        }
    }

    /// The n heaviest come out the same whichever form picks them, and equal a sort of all
    /// held records by weight (descending), then candidate key, with zero and NaN weights left
    /// out; ties of weight are common here (weights drawn from a few values).
    #[test]
    fn every_form_keeps_the_same_heaviest_records() {
        let keep_max = MAX_KEEP;
        for case in 0..400u64 {
            let mut hits = Hits {
                len: (case % 17) as usize,
                ..Hits::default()
            };
            for i in 0..HIT_LANES {
                let k = case * 100 + i as u64;
                hits.weight[i] = match (unit(31, k) * 6.0) as u32 {
                    0 => 0.0,
                    1 if i % 5 == 0 => f32::NAN,
                    v => v as f32 / 8.0,
                };
                // Distinct keys (ids differ), some sharing a distance.
                let d2 = (unit(32, k) * 3.0).floor() / 4.0;
                hits.key[i] = candidate_key(d2, (unit(33, k) * 1e6) as u32 * 64 + i as u32);
            }
            let keep = 1 + (case as usize / 17) % keep_max;
            let mut want: Vec<usize> = (0..hits.len).filter(|&i| hits.weight[i] > 0.0).collect();
            want.sort_by(|&a, &b| {
                hits.weight[b]
                    .total_cmp(&hits.weight[a])
                    .then(hits.key[a].cmp(&hits.key[b]))
            });
            want.truncate(keep);
            let best = want.first().map_or(0.0, |&i| hits.weight[i]);
            let run = |f: &dyn Fn(&mut [usize; MAX_KEEP]) -> (usize, f32)| {
                let mut order = [usize::MAX; MAX_KEEP];
                let (len, top) = f(&mut order);
                (order[..len].to_vec(), top.to_bits())
            };
            let expected = (want.clone(), best.to_bits());
            assert_eq!(
                run(&|o| hits.heaviest_portable(keep, o)),
                expected,
                "case {case}"
            );
            assert_eq!(
                run(&|o| hits.heaviest(keep, o)),
                expected,
                "dispatched, case {case}"
            );
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the feature was detected just before.
                let avx = run(&|o| unsafe { hits.heaviest_avx512(keep, o) });
                assert_eq!(avx, expected, "AVX-512, case {case}");
            }
        }
    }
}
