//! Which vector instructions this CPU has, detected once per process, for the few kernels
//! that carry hand-vectorised forms (xor-popcount of records, masked sums of the control
//! variate, the BVH's box tests). Every kernel also has a portable form that gives the same
//! answer bit for bit. Kernels written once, generic over the instruction set
//! ([`Kernel`]), are compiled for each by [`dispatch`].

/// The vector instruction sets a kernel may choose between, weakest first. Each level
/// includes everything below it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
#[repr(u8)]
pub enum SimdLevel {
    /// Plain Rust (whatever the compile target allows).
    Portable = 0,
    /// The `popcnt` instruction.
    Popcnt = 1,
    /// AVX2 (with `popcnt`): four `f64` or `u64` lanes.
    Avx2 = 2,
    /// AVX-512 F, VL and VPOPCNTDQ (with AVX2 and `popcnt`): eight lanes, mask registers,
    /// and 32 vector registers for 256-bit code.
    Avx512 = 3,
}

impl SimdLevel {
    /// The level's name: "portable", "popcnt", "avx2" or "avx512".
    pub const fn name(self) -> &'static str {
        match self {
            SimdLevel::Portable => "portable",
            SimdLevel::Popcnt => "popcnt",
            SimdLevel::Avx2 => "avx2",
            SimdLevel::Avx512 => "avx512",
        }
    }
}

/// The detected [`SimdLevel`] as a `u8` (`u8::MAX` until detected). A relaxed atomic rather
/// than a `OnceLock`: the check sits on paths of a few nanoseconds.
static LEVEL: std::sync::atomic::AtomicU8 = std::sync::atomic::AtomicU8::new(u8::MAX);

/// This CPU's [`SimdLevel`] (detected on the first call).
#[inline]
pub fn level() -> SimdLevel {
    use std::sync::atomic::Ordering::Relaxed;
    const LEVELS: [SimdLevel; 4] = [
        SimdLevel::Portable,
        SimdLevel::Popcnt,
        SimdLevel::Avx2,
        SimdLevel::Avx512,
    ];
    if let Some(&level) = LEVELS.get(LEVEL.load(Relaxed) as usize) {
        return level;
    }
    let level = detect();
    LEVEL.store(level as u8, Relaxed);
    level
}

/// Whether [`level`] has been detected as [`SimdLevel::Avx512`]: one load (false before the
/// first [`level`] call), the check of [`dispatch_avx512_detected`]. Private so that no
/// kernel chooses its instruction set but through a dispatcher of this module.
#[inline]
fn is_avx512() -> bool {
    LEVEL.load(std::sync::atomic::Ordering::Relaxed) == SimdLevel::Avx512 as u8
}

/// Whether this CPU has `at` (and so every level below it).
#[inline]
pub fn has(at: SimdLevel) -> bool {
    level() >= at
}

mod sealed {
    /// Keeps [`super::Level`] to the types of this module: a value of one is a proof.
    pub trait Sealed {}
}

/// An instruction set as a type, for code generic over it: a value of one exists only on
/// a CPU that has [`Level::LEVEL`], so generic code may use that set's instructions
/// (unsafe intrinsics whose safety is the value's existence). [`dispatch`] and [`run_at`]
/// make the values.
pub trait Level: Copy + sealed::Sealed {
    /// The instruction set this type stands for.
    const LEVEL: SimdLevel;
}

/// [`SimdLevel::Portable`] as a [`Level`]: any CPU.
#[derive(Clone, Copy, Debug)]
pub struct Portable;

impl sealed::Sealed for Portable {}
impl Level for Portable {
    const LEVEL: SimdLevel = SimdLevel::Portable;
}

/// [`SimdLevel::Popcnt`] as a [`Level`]: made only on CPUs with `popcnt`, for the kernels
/// that ask [`dispatch`] for a form at that level ([`Kernel::POPCNT`]).
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub struct Popcnt(());

#[cfg(target_arch = "x86_64")]
impl sealed::Sealed for Popcnt {}
#[cfg(target_arch = "x86_64")]
impl Level for Popcnt {
    const LEVEL: SimdLevel = SimdLevel::Popcnt;
}

/// [`SimdLevel::Avx2`] as a [`Level`]: made only on CPUs with AVX2 (and `popcnt`), for
/// code compiled with AVX2.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub struct Avx2(());

#[cfg(target_arch = "x86_64")]
impl sealed::Sealed for Avx2 {}
#[cfg(target_arch = "x86_64")]
impl Level for Avx2 {
    const LEVEL: SimdLevel = SimdLevel::Avx2;
}

/// [`SimdLevel::Avx512`] as a [`Level`]: made only on CPUs with AVX-512 F, VL and
/// VPOPCNTDQ (and AVX2 and `popcnt`), for code compiled with all of them.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub struct Avx512(());

#[cfg(target_arch = "x86_64")]
impl sealed::Sealed for Avx512 {}
#[cfg(target_arch = "x86_64")]
impl Level for Avx512 {
    const LEVEL: SimdLevel = SimdLevel::Avx512;
}

/// A computation with one body generic over the instruction set, compiled by [`dispatch`]
/// once per [`Level`], each time inside a function compiled for that set. `run`, and what
/// it calls on the hot path, must be `#[inline(always)]` functions, not closures: a
/// function left as a call is compiled for the portable target, without the set's
/// instructions, and a closure takes the (absent) target features of the generic function
/// that defines it.
pub trait Kernel {
    /// What the computation returns.
    type Output;
    /// Whether [`dispatch`] compiles `run` for [`SimdLevel::Popcnt`] too, for CPUs with
    /// `popcnt` but not AVX2. False by default: such CPUs run the portable body, whose code
    /// differs from a `popcnt` build only in its bit counts, and a fourth copy of every
    /// kernel would not pay; kernels that are mostly bit counts say true.
    const POPCNT: bool = false;
    /// The body, at instruction set `L` (`level` is the proof that the CPU has it).
    fn run<L: Level>(self, level: L) -> Self::Output;
}

/// Runs `kernel` compiled for this CPU's best instruction set among AVX-512, AVX2 and the
/// portable one (a CPU with `popcnt` alone runs the portable body, or the `popcnt` build
/// for kernels that ask for one, [`Kernel::POPCNT`]).
#[inline(always)]
pub fn dispatch<K: Kernel>(kernel: K) -> K::Output {
    #[cfg(target_arch = "x86_64")]
    match level() {
        // SAFETY: the CPU has the AVX-512 level.
        SimdLevel::Avx512 => return unsafe { run_avx512(kernel) },
        // SAFETY: the CPU has AVX2 and popcnt.
        SimdLevel::Avx2 => return unsafe { run_avx2(kernel) },
        // SAFETY: the CPU has popcnt.
        SimdLevel::Popcnt if K::POPCNT => return unsafe { run_popcnt(kernel) },
        _ => {}
    }
    kernel.run(Portable)
}

/// Runs `kernel` compiled for AVX-512 on a CPU with it ([`has`]), else its portable body
/// inlined where this is called, as the base target compiles it: for kernels with an
/// AVX-512 form and a portable one only, on CPUs without AVX-512 the same code as a call of
/// the portable form ([`dispatch`] would compile that body for AVX2 on CPUs with AVX2).
#[inline(always)]
pub fn dispatch_avx512<K: Kernel>(kernel: K) -> K::Output {
    #[cfg(target_arch = "x86_64")]
    if has(SimdLevel::Avx512) {
        // SAFETY: the CPU has the AVX-512 level.
        return unsafe { run_avx512(kernel) };
    }
    kernel.run(Portable)
}

/// [`dispatch_avx512`] by a check of one load, without detecting the level: the portable
/// body until something has called [`level`] (or a dispatcher). For kernels on paths of a
/// few nanoseconds whose portable body falls back on [`dispatch`] (which detects), such as
/// the straight-line xor-popcount of 32² maps.
#[inline(always)]
pub fn dispatch_avx512_detected<K: Kernel>(kernel: K) -> K::Output {
    #[cfg(target_arch = "x86_64")]
    if is_avx512() {
        // SAFETY: the CPU has the AVX-512 level.
        return unsafe { run_avx512(kernel) };
    }
    kernel.run(Portable)
}

/// Runs `kernel` compiled for `at` when this CPU has it, else None: tests hold each
/// instruction set's form to the portable one. [`SimdLevel::Popcnt`] runs what
/// [`dispatch`] runs on a CPU of that level (the portable body unless
/// [`Kernel::POPCNT`]).
pub fn run_at<K: Kernel>(at: SimdLevel, kernel: K) -> Option<K::Output> {
    if !has(at) {
        return None;
    }
    #[cfg(target_arch = "x86_64")]
    match at {
        // SAFETY: the CPU has the AVX-512 level (checked above).
        SimdLevel::Avx512 => return Some(unsafe { run_avx512(kernel) }),
        // SAFETY: the CPU has AVX2 and popcnt (checked above).
        SimdLevel::Avx2 => return Some(unsafe { run_avx2(kernel) }),
        // SAFETY: the CPU has popcnt (checked above).
        SimdLevel::Popcnt if K::POPCNT => return Some(unsafe { run_popcnt(kernel) }),
        _ => {}
    }
    Some(kernel.run(Portable))
}

/// [`Kernel::run`] compiled for `popcnt` alone.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "popcnt")]
fn run_popcnt<K: Kernel>(kernel: K) -> K::Output {
    kernel.run(Popcnt(()))
}

/// [`Kernel::run`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn run_avx2<K: Kernel>(kernel: K) -> K::Output {
    kernel.run(Avx2(()))
}

/// [`Kernel::run`] compiled for the whole AVX-512 level: the 256-bit code of AVX2 with 32
/// vector registers and mask registers, and `vpopcntq` and `popcnt`, so that the kernels'
/// AVX-512 forms (which enable some of these) are inlined into it rather than called.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512vl,avx512vpopcntdq,popcnt")]
fn run_avx512<K: Kernel>(kernel: K) -> K::Output {
    kernel.run(Avx512(()))
}

#[cfg(target_arch = "x86_64")]
fn detect() -> SimdLevel {
    use std::arch::is_x86_feature_detected as has;
    if !has!("popcnt") {
        SimdLevel::Portable
    } else if !has!("avx2") {
        SimdLevel::Popcnt
    } else if !(has!("avx512f") && has!("avx512vl") && has!("avx512vpopcntdq")) {
        SimdLevel::Avx2
    } else {
        SimdLevel::Avx512
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn detect() -> SimdLevel {
    SimdLevel::Portable
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_level_is_detected_once_and_agrees_with_the_fast_check() {
        let first = level();
        assert_eq!(level(), first);
        assert_eq!(is_avx512(), first == SimdLevel::Avx512);
        #[cfg(target_arch = "x86_64")]
        if first >= SimdLevel::Avx2 {
            assert!(std::arch::is_x86_feature_detected!("avx2"));
        }
    }

    /// Reports the level it was compiled for; `P` is its [`Kernel::POPCNT`].
    struct WhichLevel<const P: bool>;

    impl<const P: bool> Kernel for WhichLevel<P> {
        type Output = SimdLevel;
        const POPCNT: bool = P;

        fn run<L: Level>(self, _level: L) -> SimdLevel {
            L::LEVEL
        }
    }

    #[test]
    fn dispatchers_run_kernels_at_the_detected_level_and_popcnt_only_when_asked() {
        let best = level();
        // Without a popcnt form, a popcnt-only CPU runs the portable body.
        let plain = if best == SimdLevel::Popcnt {
            SimdLevel::Portable
        } else {
            best
        };
        assert_eq!(dispatch(WhichLevel::<true>), best);
        assert_eq!(dispatch(WhichLevel::<false>), plain);
        let avx512 = |l| {
            if l == SimdLevel::Avx512 {
                l
            } else {
                SimdLevel::Portable
            }
        };
        assert_eq!(dispatch_avx512(WhichLevel::<true>), avx512(best));
        assert_eq!(dispatch_avx512_detected(WhichLevel::<true>), avx512(best));
        for at in [
            SimdLevel::Portable,
            SimdLevel::Popcnt,
            SimdLevel::Avx2,
            SimdLevel::Avx512,
        ] {
            let (with, without) = (
                run_at(at, WhichLevel::<true>),
                run_at(at, WhichLevel::<false>),
            );
            if at <= best {
                assert_eq!(with, Some(at), "{}", at.name());
                let plain = if at == SimdLevel::Popcnt {
                    SimdLevel::Portable
                } else {
                    at
                };
                assert_eq!(without, Some(plain), "{}", at.name());
            } else {
                assert_eq!((with, without), (None, None), "{}", at.name());
            }
        }
    }
}
