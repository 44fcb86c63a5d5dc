//! Deterministic insertion in waves: how every cache grows over a set of points (a camera's
//! pixels, points a render handed over) so that the result is the same for any thread
//! count.
//!
//! Points come in levels (for pixels, coarse to fine: [`coarse_to_fine_levels`]) and, within
//! a level, in waves of a quarter of the records held ([`wave_size`]). A wave looks up its
//! points in parallel (the cache's insertion test, [`WaveTarget::wants`]); splits the points
//! that want a record into requests and points deferred to the next wave
//! ([`split_requests`]); makes the requests' records in parallel
//! ([`WaveTarget::make`], the record constructor); then inserts them in request order
//! under the write lock, re-checking each against the records inserted before it
//! ([`WaveTarget::insert`]). Between waves it reports progress, and stops when the
//! progress callback says so or the time budget is spent.

use std::ops::{Deref, DerefMut};
use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;

use crate::error::Result;
use crate::stop::Stop;

/// Most points looked up per wave.
pub const BUILD_WAVE: usize = 4096;
/// Fewest points per wave (fewer would leave threads idle).
pub const MIN_BUILD_WAVE: usize = 32;

/// Points in the next wave for a cache of `records` records: a quarter of them (so a wave
/// rarely asks twice for the same neighbourhood before either record exists), in
/// `MIN_BUILD_WAVE..=BUILD_WAVE`. A function of the cache alone, hence deterministic.
pub fn wave_size(records: usize) -> usize {
    (records / 4).clamp(MIN_BUILD_WAVE, BUILD_WAVE)
}

/// A cache as the [`WaveBuilder`] grows it. Points are indices `u32` into the caller's set.
pub trait WaveTarget: Sync {
    /// The state lookups read and insertions change (behind the cache's lock).
    type State: Sync;
    /// A record made for a point, not yet inserted.
    type Record: Send + Sync;

    /// The state under a shared lock.
    fn read(&self) -> impl Deref<Target = Self::State> + '_;

    /// The state under an exclusive lock.
    fn write(&self) -> impl DerefMut<Target = Self::State> + '_;

    /// Records the cache holds now.
    fn records(&self) -> usize;

    /// Position, unit normal and search radius (world units) of point `i`: requests closer
    /// than half the radius to an earlier one with a near normal are deferred.
    fn point(&self, i: u32) -> (Vec3, Vec3, f32);

    /// `cos θ_max`: normals closer than this count as near for deferring.
    fn cos_max(&self) -> f32;

    /// The insertion test: does point `i` want a record of its own in `state`?
    fn wants(&self, state: &Self::State, i: u32) -> bool;

    /// Cuts the wave's `requests` (and `deferred` points) down to what the cache can take
    /// before anything is made (by default, everything).
    fn limit(&self, _requests: &mut Vec<u32>, _deferred: &mut Vec<u32>) {}

    /// The record constructor: makes the record of point `i` (in parallel, no lock held).
    fn make(&self, i: u32) -> Result<Self::Record>;

    /// Inserts `record`, made for point `i`, when [`Self::wants`] still holds in `state`,
    /// counting its cost either way; true when it went in.
    fn insert(&self, state: &mut Self::State, i: u32, record: &Self::Record) -> Result<bool>;

    /// Counts `count` lookups made for the wave (by default, nothing).
    fn looked_up(&self, _count: usize) {}
}

/// What [`WaveBuilder::run`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WaveReport {
    /// Records inserted.
    pub inserted: usize,
    /// Records made but found unneeded on re-check (or refused) at insertion.
    pub discarded: usize,
    /// Points done (looked up and, if they wanted a record, served).
    pub done: usize,
    /// False when the time budget or the progress callback stopped the run early.
    pub complete: bool,
}

/// Runs the waves (module docs), with progress reports and a time budget.
pub struct WaveBuilder<'p> {
    start: Instant,
    time_budget: Option<f64>,
    progress: &'p mut (dyn FnMut(usize, usize) -> bool + Send),
}

impl<'p> WaveBuilder<'p> {
    /// A builder whose `time_budget` (seconds, checked between waves) counts from `start`;
    /// `progress(done, total)` is called after every wave and stops the run by returning
    /// false.
    pub fn new(
        start: Instant,
        time_budget: Option<f64>,
        progress: &'p mut (dyn FnMut(usize, usize) -> bool + Send),
    ) -> Self {
        Self {
            start,
            time_budget,
            progress,
        }
    }

    /// Grows `target` over `levels` of points, `total` of them in all, level after level.
    /// An error (such as an interrupted record constructor, or the current [`Stop`] set,
    /// polled between waves) drops the wave being made and leaves the records of the
    /// waves before.
    pub fn run<T: WaveTarget, L: IntoIterator<Item = u32>>(
        &mut self,
        target: &T,
        levels: impl IntoIterator<Item = L>,
        total: usize,
    ) -> Result<WaveReport> {
        let mut report = WaveReport {
            complete: true,
            ..WaveReport::default()
        };
        let stop = Stop::current();
        'levels: for level in levels {
            let mut fresh = level.into_iter().peekable();
            let mut deferred: Vec<u32> = Vec::new();
            while fresh.peek().is_some() || !deferred.is_empty() {
                // Deferred points first, then fresh ones, in their order.
                let size = wave_size(target.records()).max(deferred.len());
                let mut wave = std::mem::take(&mut deferred);
                wave.extend(fresh.by_ref().take(size - wave.len()));
                stop.check("building records")?;
                let (inserted, discarded, later) = Self::wave(target, &wave)?;
                report.inserted += inserted;
                report.discarded += discarded;
                report.done += wave.len() - later.len();
                deferred = later;
                let done = report.done;
                let over = self
                    .time_budget
                    .is_some_and(|b| self.start.elapsed().as_secs_f64() >= b);
                if !(self.progress)(done, total) || (over && done < total) {
                    report.complete = done == total;
                    break 'levels;
                }
            }
        }
        Ok(report)
    }

    /// One wave; returns (inserted, discarded, deferred points).
    ///
    /// Requests next to an earlier one of the same wave are deferred to the next wave
    /// instead of made ([`split_requests`]): making both would most likely waste one.
    /// The first request always goes ahead, so every wave makes progress.
    fn wave<T: WaveTarget>(target: &T, wave: &[u32]) -> Result<(usize, usize, Vec<u32>)> {
        let wanted: Vec<u32> = {
            let state = target.read();
            let state: &T::State = &state;
            wave.par_iter()
                .copied()
                .filter(|&i| target.wants(state, i))
                .collect()
        };
        let (mut requests, mut deferred) =
            split_requests(&wanted, target.cos_max(), |i| target.point(i));
        target.looked_up(wave.len());
        target.limit(&mut requests, &mut deferred);
        let made: Vec<T::Record> = requests
            .par_iter()
            .map(|&i| target.make(i))
            .collect::<Result<_>>()?;
        let mut state = target.write();
        let (mut inserted, mut discarded) = (0, 0);
        for (&i, record) in requests.iter().zip(&made) {
            if target.insert(&mut state, i, record)? {
                inserted += 1;
            } else {
                discarded += 1;
            }
        }
        target.looked_up(requests.len());
        Ok((inserted, discarded, deferred))
    }
}

/// Splits a wave's points that want a record into requests, traced now, and points deferred
/// to the next wave: those closer than `d_max / 2` to an earlier request whose normal is
/// within `θ_max` (`cos_max`) of theirs, which that request's record will most likely
/// serve. The first point is always a request. `query(i)` gives `(position, unit normal,
/// d_max)`.
pub fn split_requests(
    wanted: &[u32],
    cos_max: f32,
    query: impl Fn(u32) -> (Vec3, Vec3, f32),
) -> (Vec<u32>, Vec<u32>) {
    let mut requests: Vec<u32> = Vec::with_capacity(wanted.len());
    let mut deferred = Vec::new();
    for &i in wanted {
        let (x, n, d) = query(i);
        let near = requests.iter().any(|&j| {
            let (y, m, _) = query(j);
            x.distance_squared(y) < 0.25 * d * d && n.dot(m) > cos_max
        });
        if near {
            deferred.push(i);
        } else {
            requests.push(i);
        }
    }
    (requests, deferred)
}

/// Pixel indices of a `w x h` image, coarse to fine, one list per level: the pixels on the
/// grid of spacing 32, then the new ones of spacing 16, …, 1; row-major within a level.
pub fn coarse_to_fine_levels(w: u32, h: u32) -> Vec<Vec<u32>> {
    let mut levels = Vec::new();
    let mut spacing = 32u32;
    loop {
        let mut level = Vec::new();
        for y in (0..h).step_by(spacing as usize) {
            for x in (0..w).step_by(spacing as usize) {
                let coarser = 2 * spacing;
                if spacing == 32 || x % coarser != 0 || y % coarser != 0 {
                    level.push(y * w + x);
                }
            }
        }
        levels.push(level);
        if spacing == 1 {
            return levels;
        }
        spacing /= 2;
    }
}
