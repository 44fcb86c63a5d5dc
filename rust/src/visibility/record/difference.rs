//! CAM08 eq. 11's count: `popcount(V_i xor V_j)` over two maps' bit words, in a form per
//! instruction set chosen by [`crate::simd`]'s dispatchers: AVX-512 `vpopcntq` (eight words
//! an instruction, so a 32² map is two), AVX2 (LLVM's nibble lookups, four words at once),
//! the `popcnt` instruction, and portable Rust. Every form gives the same count.

use crate::simd::{Kernel, Level, SimdLevel};

/// `popcount(a xor b)` over two equally long word slices. 32² maps (16 words) on AVX-512
/// take a straight-line form through the one-load check of
/// [`crate::simd::dispatch_avx512_detected`], kept small enough for this function to
/// inline into the callers' loops; everything else goes through [`xor_popcount_dispatch`].
#[inline]
pub(super) fn xor_popcount(a: &[u64], b: &[u64]) -> u32 {
    if let (Ok(a), Ok(b)) = (<&[u64; 16]>::try_from(a), <&[u64; 16]>::try_from(b)) {
        return crate::simd::dispatch_avx512_detected(Words16 { a, b });
    }
    xor_popcount_dispatch(a, b)
}

/// [`xor_popcount`] for every length and CPU (and the first call, which detects the CPU),
/// by [`crate::simd::dispatch`]. Never inlined: the callers' loops keep only the 32² path.
/// 64² and 128² maps go as [`Words`] (array references, which the call to the kernel
/// passes in registers): a kernel of two slices is passed through memory, and reading
/// the lengths back cost 3–5% of the 18 ns count at 128².
#[inline(never)]
pub(super) fn xor_popcount_dispatch(a: &[u64], b: &[u64]) -> u32 {
    if let (Ok(a), Ok(b)) = (<&[u64; 256]>::try_from(a), <&[u64; 256]>::try_from(b)) {
        return crate::simd::dispatch(Words { a, b });
    }
    if let (Ok(a), Ok(b)) = (<&[u64; 64]>::try_from(a), <&[u64; 64]>::try_from(b)) {
        return crate::simd::dispatch(Words { a, b });
    }
    crate::simd::dispatch(XorPopcount { a, b })
}

/// [`XorPopcount`] of `N` words, as two array references.
#[derive(Clone, Copy)]
pub(super) struct Words<'a, const N: usize> {
    pub(super) a: &'a [u64; N],
    pub(super) b: &'a [u64; N],
}

impl<const N: usize> Kernel for Words<'_, N> {
    type Output = u32;
    const POPCNT: bool = true;

    #[inline(always)]
    fn run<L: Level>(self, level: L) -> u32 {
        XorPopcount {
            a: self.a,
            b: self.b,
        }
        .run(level)
    }
}

/// [`xor_popcount`] of 32² maps as a [`Kernel`]: [`xor_popcount_avx512_16`] at the AVX-512
/// level, else [`xor_popcount_dispatch`]. The count itself, not an `Option` of it, comes
/// back: a flag to test after the call cost a tenth of the 3 ns count.
#[derive(Clone, Copy)]
pub(super) struct Words16<'a> {
    pub(super) a: &'a [u64; 16],
    pub(super) b: &'a [u64; 16],
}

impl Kernel for Words16<'_> {
    type Output = u32;

    #[inline(always)]
    fn run<L: Level>(self, _level: L) -> u32 {
        match L::LEVEL {
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here AVX-512 F and VPOPCNTDQ.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => unsafe { xor_popcount_avx512_16(self.a, self.b) },
            _ => xor_popcount_dispatch(self.a, self.b),
        }
    }
}

/// [`xor_popcount`] of any length as a [`Kernel`], with a `popcnt` build for CPUs that
/// have nothing more ([`Kernel::POPCNT`]): the count is all this kernel does.
#[derive(Clone, Copy)]
pub(super) struct XorPopcount<'a> {
    pub(super) a: &'a [u64],
    pub(super) b: &'a [u64],
}

impl Kernel for XorPopcount<'_> {
    type Output = u32;
    const POPCNT: bool = true;

    #[inline(always)]
    fn run<L: Level>(self, _level: L) -> u32 {
        let (a, b) = (self.a, self.b);
        // SAFETY (each vector form): a value of `L` exists only on CPUs with `L::LEVEL`
        // (`Level`'s contract), and each level includes the sets its form enables.
        match L::LEVEL {
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 if a.len() >= 8 => unsafe { xor_popcount_avx512(a, b) },
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx2 if a.len() >= 8 => unsafe { xor_popcount_avx2(a, b) },
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Popcnt | SimdLevel::Avx2 | SimdLevel::Avx512 => unsafe {
                xor_popcount_popcnt(a, b)
            },
            _ => xor_popcount_portable(a, b),
        }
    }
}

/// `popcount(a xor b)`, portable form (LLVM vectorises it or uses `popcnt` when the target
/// allows).
#[inline(always)]
pub(super) fn xor_popcount_portable(a: &[u64], b: &[u64]) -> u32 {
    a.iter().zip(b).map(|(x, y)| (x ^ y).count_ones()).sum()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "popcnt")]
fn xor_popcount_popcnt(a: &[u64], b: &[u64]) -> u32 {
    xor_popcount_portable(a, b)
}

/// With AVX2 LLVM vectorises the loop (nibble lookups with `vpshufb`, four words at once).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
fn xor_popcount_avx2(a: &[u64], b: &[u64]) -> u32 {
    xor_popcount_portable(a, b)
}

/// AVX-512 with `vpopcntq`: eight words per instruction, the tail by `popcnt`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vpopcntdq,popcnt")]
fn xor_popcount_avx512(a: &[u64], b: &[u64]) -> u32 {
    use std::arch::x86_64::*;
    let n = a.len().min(b.len());
    let mut sum = _mm512_setzero_si512();
    let mut k = 0;
    while k + 8 <= n {
        // SAFETY: `k + 8 <= n` words remain in both slices; unaligned loads.
        let (x, y) = unsafe {
            (
                _mm512_loadu_si512(a.as_ptr().add(k).cast()),
                _mm512_loadu_si512(b.as_ptr().add(k).cast()),
            )
        };
        sum = _mm512_add_epi64(sum, _mm512_popcnt_epi64(_mm512_xor_si512(x, y)));
        k += 8;
    }
    _mm512_reduce_add_epi64(sum) as u32 + xor_popcount_portable(&a[k..n], &b[k..n])
}

/// [`xor_popcount_avx512`] for 32² maps (16 words), straight-line: at a few nanoseconds a
/// call, the generic loop's length checks and tail cost as much as the counting.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vpopcntdq")]
fn xor_popcount_avx512_16(a: &[u64; 16], b: &[u64; 16]) -> u32 {
    use std::arch::x86_64::*;
    // SAFETY: both arrays hold 16 words, two unaligned 8-word loads each.
    let (a0, a1, b0, b1) = unsafe {
        (
            _mm512_loadu_si512(a.as_ptr().cast()),
            _mm512_loadu_si512(a.as_ptr().add(8).cast()),
            _mm512_loadu_si512(b.as_ptr().cast()),
            _mm512_loadu_si512(b.as_ptr().add(8).cast()),
        )
    };
    let counts = _mm512_add_epi64(
        _mm512_popcnt_epi64(_mm512_xor_si512(a0, b0)),
        _mm512_popcnt_epi64(_mm512_xor_si512(a1, b1)),
    );
    _mm512_reduce_add_epi64(counts) as u32
}
