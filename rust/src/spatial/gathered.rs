//! Records gathered around a lookup point as structure of arrays, and the per-lookup
//! filter by distance and normal that runs over them sixteen at a time (CAM08 §5.1's
//! candidate set). The kd-tree appends to them ([`super::tree`]); the scratch of a lookup
//! holds them ([`super::scratch`]).

use glam::Vec3;

use crate::simd::{Kernel, Level, SimdLevel};

/// A record as the index holds it: position, unit normal, id.
pub(super) type Entry = (Vec3, Vec3, u32);

/// Lanes of the filter: the gathered arrays are padded to a multiple of this.
const LANES: usize = 16;

/// Gathered records as structure of arrays (position, decoded normal, id), padded to whole
/// groups of [`LANES`] with positions of NaN, which no distance test passes.
#[derive(Clone, Debug, Default)]
pub(super) struct GatheredSites {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    nx: Vec<f32>,
    ny: Vec<f32>,
    nz: Vec<f32>,
    id: Vec<u32>,
    /// Records held (the arrays are longer by the padding).
    len: usize,
}

impl GatheredSites {
    pub(super) fn clear(&mut self) {
        for v in [
            &mut self.x,
            &mut self.y,
            &mut self.z,
            &mut self.nx,
            &mut self.ny,
            &mut self.nz,
        ] {
            v.clear();
        }
        self.id.clear();
        self.len = 0;
    }

    pub(super) fn push(&mut self, (position, normal, id): Entry) {
        self.x.push(position.x);
        self.y.push(position.y);
        self.z.push(position.z);
        self.nx.push(normal.x);
        self.ny.push(normal.y);
        self.nz.push(normal.z);
        self.id.push(id);
        self.len += 1;
    }

    /// Appends the lanes of sixteen records set in `pass`: `lanes` holds their x, y, z
    /// positions and normals, `id` their ids. Compresses in registers and stores whole
    /// vectors (room for them is reserved first), then counts only the passing lanes.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    pub(super) fn append_masked_avx512(
        &mut self,
        pass: u16,
        lanes: [std::arch::x86_64::__m512; 6],
        id: std::arch::x86_64::__m512i,
    ) {
        use std::arch::x86_64::*;
        let count = pass.count_ones() as usize;
        let arrays = [
            &mut self.x,
            &mut self.y,
            &mut self.z,
            &mut self.nx,
            &mut self.ny,
            &mut self.nz,
        ];
        for (v, lane) in arrays.into_iter().zip(lanes) {
            v.reserve(LANES);
            // SAFETY: the reserve leaves room for 16 values past the length; the first
            // `count` written are initialised values, and only they are taken in.
            unsafe {
                store_compressed(v.as_mut_ptr().add(v.len()), pass, lane);
                v.set_len(v.len() + count);
            }
        }
        self.id.reserve(LANES);
        // SAFETY: as above.
        unsafe {
            let end = self.id.as_mut_ptr().add(self.id.len());
            _mm512_storeu_si512(end.cast(), _mm512_maskz_compress_epi32(pass, id));
            self.id.set_len(self.id.len() + count);
        }
        self.len += count;
    }

    /// Pads the arrays to whole groups of lanes; call after the last [`Self::push`].
    pub(super) fn seal(&mut self) {
        let padded = self.len.next_multiple_of(LANES);
        for v in [&mut self.x, &mut self.y, &mut self.z] {
            v.resize(padded, f32::NAN);
        }
        for v in [&mut self.nx, &mut self.ny, &mut self.nz] {
            v.resize(padded, 0.0);
        }
        self.id.resize(padded, u32::MAX);
    }

    /// Records held.
    pub(super) fn len(&self) -> usize {
        self.len
    }

    pub(super) fn id(&self, k: usize) -> u32 {
        self.id[k]
    }

    pub(super) fn position(&self, k: usize) -> Vec3 {
        Vec3::new(self.x[k], self.y[k], self.z[k])
    }

    pub(super) fn normal(&self, k: usize) -> Vec3 {
        Vec3::new(self.nx[k], self.ny[k], self.nz[k])
    }

    /// Writes into `out` the records with `|p − x|² <= r2` and `n · n_i >= cos_lo` (NaN
    /// passes neither), in gathered order, with what scoring needs of them. The squared
    /// distance is summed as the tree's range query sums it, and `n · n_i`, `|n × n_i|`
    /// and `n · (p_i − x)` as glam computes them, so every form (and a range query at `x`)
    /// decides and scores alike.
    pub(super) fn filter(&self, x: Vec3, n: Vec3, r2: f32, cos_lo: f32, out: &mut Passed) {
        crate::simd::dispatch_avx512(FilterKernel {
            sites: self,
            x,
            n,
            r2,
            cos_lo,
            out,
        });
    }

    /// [`Self::filter`] one record at a time (branches: on scenes where nearly every
    /// gathered record is out of reach they predict well).
    pub(super) fn filter_portable(&self, x: Vec3, n: Vec3, r2: f32, cos_lo: f32, out: &mut Passed) {
        out.clear();
        for k in 0..self.len {
            let (ex, ey, ez) = (self.x[k] - x.x, self.y[k] - x.y, self.z[k] - x.z);
            let d2 = ex * ex + ey * ey + ez * ez;
            if d2 <= r2 {
                let cos = n.dot(self.normal(k));
                if cos >= cos_lo {
                    out.index.push(k as u32);
                    out.d2.push(d2);
                    out.cos.push(cos);
                    out.sin.push(n.cross(self.normal(k)).length());
                    out.along.push(n.dot(Vec3::new(ex, ey, ez)));
                }
            }
        }
    }

    /// [`Self::filter`] sixteen records at a time: the tests give a mask, and the passing
    /// lanes are compressed in registers and stored whole (a compressing store to memory
    /// is microcoded and slow on some CPUs), the end advancing by the mask's popcount.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[inline(never)]
    pub(super) fn filter_avx512(&self, x: Vec3, n: Vec3, r2: f32, cos_lo: f32, out: &mut Passed) {
        use std::arch::x86_64::*;
        let padded = self.x.len();
        debug_assert_eq!(padded % LANES, 0);
        // Whole stores of 16 lanes past the last passing record need room (reserved, not
        // filled: the stores initialise what the lengths take in at the end).
        out.clear();
        out.index.reserve(padded + LANES);
        out.d2.reserve(padded + LANES);
        out.cos.reserve(padded + LANES);
        out.sin.reserve(padded + LANES);
        out.along.reserve(padded + LANES);
        let q = [x.x, x.y, x.z].map(|v| _mm512_set1_ps(v));
        let (mx, my, mz) = (
            _mm512_set1_ps(n.x),
            _mm512_set1_ps(n.y),
            _mm512_set1_ps(n.z),
        );
        let (reach, lo) = (_mm512_set1_ps(r2), _mm512_set1_ps(cos_lo));
        let lane = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        let mut len = 0usize;
        for c in (0..padded).step_by(LANES) {
            // SAFETY: `c + 16 <= padded`, the length of every gathered array, and
            // `len + 16 <= padded + 16`, the capacity of every output array.
            unsafe {
                let ([ex, ey, ez], d2) = offsets_avx512(
                    self.x.as_ptr().add(c),
                    self.y.as_ptr().add(c),
                    self.z.as_ptr().add(c),
                    q,
                );
                let within = _mm512_cmp_ps_mask::<_CMP_LE_OQ>(d2, reach);
                if within == 0 {
                    continue;
                }
                let (nx, ny, nz) = (
                    _mm512_loadu_ps(self.nx.as_ptr().add(c)),
                    _mm512_loadu_ps(self.ny.as_ptr().add(c)),
                    _mm512_loadu_ps(self.nz.as_ptr().add(c)),
                );
                let cos = _mm512_add_ps(
                    _mm512_add_ps(_mm512_mul_ps(mx, nx), _mm512_mul_ps(my, ny)),
                    _mm512_mul_ps(mz, nz),
                );
                let pass = within & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(cos, lo);
                if pass == 0 {
                    continue;
                }
                // glam's `n.cross(n_i).length()` and `n.dot(p_i − x)`, operation for
                // operation.
                let cx = _mm512_sub_ps(_mm512_mul_ps(my, nz), _mm512_mul_ps(ny, mz));
                let cy = _mm512_sub_ps(_mm512_mul_ps(mz, nx), _mm512_mul_ps(nz, mx));
                let cz = _mm512_sub_ps(_mm512_mul_ps(mx, ny), _mm512_mul_ps(nx, my));
                let sin = _mm512_sqrt_ps(_mm512_add_ps(
                    _mm512_add_ps(_mm512_mul_ps(cx, cx), _mm512_mul_ps(cy, cy)),
                    _mm512_mul_ps(cz, cz),
                ));
                let along = _mm512_add_ps(
                    _mm512_add_ps(_mm512_mul_ps(mx, ex), _mm512_mul_ps(my, ey)),
                    _mm512_mul_ps(mz, ez),
                );
                let index = _mm512_add_epi32(lane, _mm512_set1_epi32(c as i32));
                _mm512_storeu_si512(
                    out.index.as_mut_ptr().add(len).cast(),
                    _mm512_maskz_compress_epi32(pass, index),
                );
                for (to, v) in [
                    (&mut out.d2, d2),
                    (&mut out.cos, cos),
                    (&mut out.sin, sin),
                    (&mut out.along, along),
                ] {
                    store_compressed(to.as_mut_ptr().add(len), pass, v);
                }
                len += pass.count_ones() as usize;
            }
        }
        // SAFETY: the stores wrote every lane up to `len` (and past it) within the
        // capacity reserved above.
        unsafe {
            out.index.set_len(len);
            out.d2.set_len(len);
            out.cos.set_len(len);
            out.sin.set_len(len);
            out.along.set_len(len);
        }
    }
}

/// The offsets `p − x` by axis and the squared distances `|p − x|²` of sixteen records
/// whose coordinates start at `xs`, `ys` and `zs`, from `x` splatted in `q`. The sum is
/// the portable forms' (no fused multiply-adds: they round every product), so the range
/// query, the filter and their portable forms all decide alike.
///
/// # Safety
/// Sixteen `f32`s must be readable from each pointer.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub(super) unsafe fn offsets_avx512(
    xs: *const f32,
    ys: *const f32,
    zs: *const f32,
    q: [std::arch::x86_64::__m512; 3],
) -> ([std::arch::x86_64::__m512; 3], std::arch::x86_64::__m512) {
    use std::arch::x86_64::*;
    // SAFETY: the caller's.
    let (ex, ey, ez) = unsafe {
        (
            _mm512_sub_ps(_mm512_loadu_ps(xs), q[0]),
            _mm512_sub_ps(_mm512_loadu_ps(ys), q[1]),
            _mm512_sub_ps(_mm512_loadu_ps(zs), q[2]),
        )
    };
    let d2 = _mm512_add_ps(
        _mm512_add_ps(_mm512_mul_ps(ex, ex), _mm512_mul_ps(ey, ey)),
        _mm512_mul_ps(ez, ez),
    );
    ([ex, ey, ez], d2)
}

/// `v`'s lanes set in `keep`, packed to the front, stored as sixteen lanes at `to`.
///
/// # Safety
/// Sixteen `f32`s must be writable at `to`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn store_compressed(to: *mut f32, keep: u16, v: std::arch::x86_64::__m512) {
    use std::arch::x86_64::*;
    // SAFETY: the caller's.
    unsafe { _mm512_storeu_ps(to, _mm512_maskz_compress_ps(keep, v)) }
}

/// [`GatheredSites::filter`] as a [`Kernel`]: its AVX-512 form, else the portable one. The
/// AVX-512 form is never inlined into the dispatcher's function, whose feature set differs
/// (AVX-512 VL): it stays compiled exactly for its own set.
struct FilterKernel<'a> {
    sites: &'a GatheredSites,
    x: Vec3,
    n: Vec3,
    r2: f32,
    cos_lo: f32,
    out: &'a mut Passed,
}

impl Kernel for FilterKernel<'_> {
    type Output = ();

    #[inline(always)]
    fn run<L: Level>(self, _level: L) {
        let Self {
            sites,
            x,
            n,
            r2,
            cos_lo,
            out,
        } = self;
        match L::LEVEL {
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here AVX-512 F.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => unsafe { sites.filter_avx512(x, n, r2, cos_lo, out) },
            _ => sites.filter_portable(x, n, r2, cos_lo, out),
        }
    }
}

/// What [`GatheredSites::filter`] lets through: gathered indices with their squared
/// distance, `cos θ` (`n · n_i`), `sin θ` (`|n × n_i|`) and `n · (p_i − x)`, in gathered
/// order.
#[derive(Clone, Debug, Default, PartialEq)]
pub(super) struct Passed {
    pub(super) index: Vec<u32>,
    pub(super) d2: Vec<f32>,
    pub(super) cos: Vec<f32>,
    pub(super) sin: Vec<f32>,
    pub(super) along: Vec<f32>,
}

impl Passed {
    fn clear(&mut self) {
        self.index.clear();
        for v in [&mut self.d2, &mut self.cos, &mut self.sin, &mut self.along] {
            v.clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::{hash4, to_unit_f32};

    fn unit(seed: u64, k: u64) -> f32 {
        to_unit_f32(hash4(seed, k, 0, 5))
    }

    /// Gathered records around the origin: some share a position on the reach of
    /// `r2 = 0.0625`, some lie exactly at the origin, one has a NaN normal.
    fn gathered(count: usize, seed: u64) -> GatheredSites {
        let mut sites = GatheredSites::default();
        for k in 0..count as u64 {
            let mut position = Vec3::new(
                unit(seed, 3 * k),
                unit(seed, 3 * k + 1),
                unit(seed, 3 * k + 2),
            ) - 0.5;
            if k % 11 == 3 {
                position = Vec3::new(0.25, 0.0, 0.0);
            } else if k % 13 == 4 {
                position = Vec3::ZERO;
            }
            let tilt = 1.5 * unit(seed + 1, k);
            let mut normal = Vec3::new(tilt.sin(), tilt.cos(), 0.0);
            if k == 5 {
                normal = Vec3::NAN;
            }
            sites.push((position, normal, 1000 + k as u32));
        }
        sites.seal();
        sites
    }

    #[test]
    fn every_filter_form_passes_the_same_records_with_the_same_bits() {
        let n = Vec3::Y;
        for count in [0usize, 1, 15, 16, 17, 100, 333] {
            let sites = gathered(count, count as u64);
            for (r2, cos_lo) in [(0.0625f32, 0.8f32), (0.01, -1.0), (1.0, 0.99), (0.0, 0.0)] {
                let mut want = Passed::default();
                sites.filter_portable(Vec3::ZERO, n, r2, cos_lo, &mut want);
                // The portable form against the definition, record by record.
                let expected: Vec<u32> = (0..count)
                    .filter(|&k| {
                        let p = sites.position(k);
                        p.length_squared() <= r2 && n.dot(sites.normal(k)) >= cos_lo
                    })
                    .map(|k| k as u32)
                    .collect();
                assert_eq!(want.index, expected, "{count} records, r2 {r2}");
                assert!(!want.index.contains(&5), "a NaN normal never passes");
                let mut got = Passed::default();
                sites.filter(Vec3::ZERO, n, r2, cos_lo, &mut got);
                let bits = |p: &Passed| {
                    let f = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    (
                        p.index.clone(),
                        [&p.d2, &p.cos, &p.sin, &p.along].map(|v| f(v)),
                    )
                };
                assert_eq!(bits(&got), bits(&want), "dispatched, {count} records");
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx512f") {
                    let mut wide = Passed::default();
                    // SAFETY: the feature was detected just before.
                    unsafe { sites.filter_avx512(Vec3::ZERO, n, r2, cos_lo, &mut wide) };
                    assert_eq!(bits(&wide), bits(&want), "AVX-512, {count} records");
                }
            }
        }
    }
}
