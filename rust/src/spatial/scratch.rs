//! The working space of lookups, kept between them: the records gathered around an
//! earlier point, serving the lookups after it while they are covered.

use glam::Vec3;

use super::candidates::Candidates;
use super::gathered::{GatheredSites, Passed};
use super::score::Hits;
use super::tree::QueryScratch;

/// Records gathered around an earlier lookup point, reused by the lookups after it while
/// their search balls lie inside the gathered one. Lookups in pixel order share most
/// records, so a range query every few pixels replaces one per pixel. Valid for one cache
/// state: any insertion or removal invalidates it (each change draws a new generation).
/// Scattered lookups (nothing to share) fall back to exact range queries by themselves.
#[derive(Clone, Debug, Default)]
pub struct LookupScratch {
    pub(super) generation: u64,
    pub(super) anchor: Vec3,
    /// The point of the last lookup.
    pub(super) previous: Vec3,
    pub(super) reach: f32,
    pub(super) sites: GatheredSites,
    /// Working space of range queries.
    pub(super) query: QueryScratch,
    /// The gathered records that pass the current lookup's distance and loose normal tests.
    pub(super) passed: Passed,
    /// The candidates of the current lookup, keyed by [`candidate_key`] so that the m
    /// nearest are a selection on one integer.
    pub(super) candidates: Candidates,
    /// The m nearest of the current lookup.
    pub(super) hits: Hits,
    /// Lookups served by the current gathering, and gatherings so far.
    pub(super) served: u32,
    pub(crate) gathers: u32,
    /// Whether the current gathering is wide, the scattered gatherings left before the next
    /// wide one is tried, and the interval between such tries (0: not yet set).
    pub(super) wide: bool,
    pub(super) until_wide: u32,
    pub(crate) wide_interval: u32,
}

impl LookupScratch {
    /// Gathered radius over the gathering lookup's `d_max`: the following lookups reuse the
    /// records while within `(REACH − 1) d_max` of the ball's centre (set up to 0.9 of that
    /// ahead of the gathering point along the walk). At 2, the gathered ball holds about 4x
    /// (flat surfaces) the records of one lookup.
    pub const REACH: f32 = 2.0;
    /// Scattered gatherings between tries of a wide one, at first and at most: the
    /// interval doubles each time a try serves one lookup alone, and returns to the first
    /// as soon as a gathering serves several.
    pub const WIDE_RETRY: (u32, u32) = (8, 64);
}

/// Whether the next gathering goes wide: always while the last one served several lookups
/// (`served > 1`); otherwise every `wide_interval`-th, the interval starting at
/// `retry.0` and doubling up to `retry.1` each time a wide try served one lookup alone.
/// Updates `wide` (to the answer), `until_wide` and `wide_interval` (0: not yet set).
pub(super) fn next_gather_is_wide(
    served: u32,
    wide: &mut bool,
    until_wide: &mut u32,
    wide_interval: &mut u32,
    (first, most): (u32, u32),
) -> bool {
    let coherent = served > 1;
    *wide_interval = if coherent || *wide_interval == 0 {
        first
    } else if *wide {
        (2 * *wide_interval).min(most)
    } else {
        *wide_interval
    };
    let next = coherent || *until_wide == 0;
    *until_wide = if next {
        *wide_interval
    } else {
        *until_wide - 1
    };
    *wide = next;
    next
}

thread_local! {
    /// The scratch of lookups made without one: its buffers are kept between calls, and
    /// a thread's consecutive lookups still share gatherings when they are close.
    static THREAD_SCRATCH: std::cell::RefCell<LookupScratch> = Default::default();
}

/// Runs `f` with this thread's [`LookupScratch`] (a fresh one if it is in use).
pub fn with_thread_scratch<R>(f: impl FnOnce(&mut LookupScratch) -> R) -> R {
    THREAD_SCRATCH.with(|cell| match cell.try_borrow_mut() {
        Ok(mut scratch) => f(&mut scratch),
        Err(_) => f(&mut LookupScratch::default()),
    })
}
