//! Tree arrays on huge pages.
//!
//! A tree larger than L2 is read at random addresses, and with 4 KiB pages each new page a
//! ray reaches costs a page walk on top of the cache miss: garden's 18 MB of nodes and leaf
//! blocks span 4,600 pages, more than the TLB holds. Where the kernel backs memory with
//! huge pages only on request (`transparent_hugepage` set to `madvise`, as on Debian), the
//! request is made here; elsewhere, and where it is refused, nothing changes.

/// Arrays smaller than this stay on ordinary pages (a huge page is 2 MiB).
const LEAST_BYTES: usize = 4 << 20;

/// `MADV_COLLAPSE` (Linux 6.1): back the range with huge pages now, copying what it holds.
#[cfg(target_os = "linux")]
const MADV_COLLAPSE: libc::c_int = 25;

/// Asks the kernel to back the memory of `items` (from [`LEAST_BYTES`], on Linux) with
/// huge pages: the whole 2 MiB pages inside it, now, and any it gains later. The contents
/// do not change, and a refusal (an older kernel, huge pages switched off) is harmless.
pub fn advise_huge_pages<T>(items: &[T]) {
    #[cfg(target_os = "linux")]
    {
        let bytes = std::mem::size_of_val(items);
        // Whole 4 KiB pages inside the array.
        let start = items.as_ptr() as usize;
        let first = start.next_multiple_of(4096);
        let end = (start + bytes) & !4095;
        if bytes >= LEAST_BYTES && end > first {
            for advice in [libc::MADV_HUGEPAGE, MADV_COLLAPSE] {
                // SAFETY: the range lies inside the array; the advice changes how its pages
                // are backed, never their contents.
                unsafe {
                    libc::madvise(first as *mut libc::c_void, end - first, advice);
                }
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = items;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Small and large arrays (below and above the threshold, of a size that is no multiple
    /// of a page) keep their contents when their pages are collapsed into huge ones.
    #[test]
    fn contents_stay() {
        for n in [0usize, 1, 1000, 3 * LEAST_BYTES / 12 + 77] {
            let make = |i: u32| [i, i ^ 0x5555, i.wrapping_mul(2_654_435_761)];
            let items: Vec<[u32; 3]> = (0..n as u32).map(make).collect();
            advise_huge_pages(&items);
            assert!(
                items.iter().zip(0..).all(|(v, i)| *v == make(i)),
                "{n} items"
            );
        }
    }
}
