//! Fallible allocation of the buffers a caller sizes (images, ray batches, copies of input
//! arrays, BVH inputs). Rust's `Vec` aborts the process when an allocation fails; under an
//! address-space limit (`RLIMIT_AS`), a container's memory cap or a 32-bit address space
//! that turns a too-large request from a user into a SIGABRT. These helpers reserve first
//! and fail with [`Error::OutOfMemory`] instead, naming what was being allocated and its
//! size, which the bindings raise as `MemoryError`.
//!
//! Where a buffer's size is known up front, reserve it whole before any work, so that the
//! failure comes at once rather than after seconds of work. Where a library allocates
//! internally (the BVH builder, the EXR codec), [`check_memory`] probes a worst-case
//! estimate first: the probe reserves address space without touching it, so it costs no
//! memory, and a request that could not be met fails there.

use crate::error::{Error, Result};

/// The error for `bytes` of `what` that could not be allocated.
pub fn out_of_memory(what: &str, bytes: usize) -> Error {
    Error::OutOfMemory {
        what: what.into(),
        bytes,
    }
}

/// Bytes taken by `len` values of `T`, saturating (a count whose size overflows `usize`
/// can never be allocated, and the error then reports `usize::MAX`).
pub fn bytes_of<T>(len: usize) -> usize {
    len.saturating_mul(std::mem::size_of::<T>())
}

/// Fails with [`Error::OutOfMemory`] when `bytes` cannot be allocated now: a fallible
/// allocation of that size, freed at once, never touched. Calls whose buffers grow with
/// their input check their total (or a library's worst case) before starting.
pub fn check_memory(bytes: usize, what: &str) -> Result<()> {
    let mut probe: Vec<u8> = Vec::new();
    probe
        .try_reserve_exact(bytes)
        .map_err(|_| out_of_memory(what, bytes))
}

/// An empty vector with room for `len` values, or [`Error::OutOfMemory`] naming `what`.
pub fn try_with_capacity<T>(len: usize, what: &str) -> Result<Vec<T>> {
    let mut v = Vec::new();
    v.try_reserve_exact(len)
        .map_err(|_| out_of_memory(what, bytes_of::<T>(len)))?;
    Ok(v)
}

/// `vec![value; len]`, or [`Error::OutOfMemory`] naming `what`.
pub fn try_filled<T: Clone>(len: usize, value: T, what: &str) -> Result<Vec<T>> {
    let mut v = try_with_capacity(len, what)?;
    v.resize(len, value);
    Ok(v)
}

/// A copy of `items`, or [`Error::OutOfMemory`] naming `what`.
pub fn try_copy<T: Clone>(items: &[T], what: &str) -> Result<Vec<T>> {
    let mut v = try_with_capacity(items.len(), what)?;
    v.extend_from_slice(items);
    Ok(v)
}

/// The values of `iter` (which knows its length) collected into a vector reserved whole
/// first, or [`Error::OutOfMemory`] naming `what`.
pub fn try_collect<T>(iter: impl ExactSizeIterator<Item = T>, what: &str) -> Result<Vec<T>> {
    let mut v = try_with_capacity(iter.len(), what)?;
    v.extend(iter);
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn impossible_sizes_are_errors_naming_what_and_how_much() {
        // More than any address space holds: refused by the allocator at once.
        let n = usize::MAX / 16;
        let e = try_with_capacity::<[f32; 3]>(n, "image").unwrap_err();
        assert!(
            matches!(&e, Error::OutOfMemory { what, bytes } if what == "image" && *bytes == n * 12),
            "{e:?}"
        );
        assert!(e.to_string().starts_with("image: needs"), "{e}");
        assert!(try_filled(usize::MAX / 2, 0u8, "x").is_err());
        assert!(check_memory(usize::MAX, "probe").is_err());
        // A count whose byte size overflows reports the saturated size.
        let e = try_with_capacity::<u64>(usize::MAX, "rays").unwrap_err();
        assert!(matches!(
            e,
            Error::OutOfMemory {
                bytes: usize::MAX,
                ..
            }
        ));
    }

    #[test]
    fn possible_sizes_give_the_values() {
        assert_eq!(try_filled(3, 7u32, "x").unwrap(), vec![7, 7, 7]);
        assert_eq!(try_copy(&[1, 2], "x").unwrap(), vec![1, 2]);
        assert_eq!(
            try_collect((0..4).map(|i| i * i), "x").unwrap(),
            [0, 1, 4, 9]
        );
        let v = try_with_capacity::<f64>(1000, "x").unwrap();
        assert!(v.is_empty() && v.capacity() >= 1000);
        check_memory(1 << 20, "x").unwrap();
    }
}
