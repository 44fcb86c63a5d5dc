//! Which vector instructions this CPU has, detected once per process, for the few kernels
//! that carry hand-vectorised forms (xor-popcount of records, masked sums of the control
//! variate). Every kernel also has a portable form that gives the same answer bit for bit.

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

/// Whether [`level`] has been detected as [`SimdLevel::Avx512`]: one load, for kernels that
/// take a straight-line AVX-512 path before anything else (false before the first
/// [`level`] call, which such kernels' fallbacks make).
#[inline]
pub fn is_avx512() -> bool {
    LEVEL.load(std::sync::atomic::Ordering::Relaxed) == SimdLevel::Avx512 as u8
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
}
