//! One index for the records of every cache: records with a position, a unit normal and a
//! validity radius, looked up by weighted `m`-nearest gathering (CAM08 §5.1, eq. 9) or by
//! reach (every record whose radius covers a point: survey ch. 3, Algorithms 2–3), with a
//! payload of the cache's own ([`Records`]).
//!
//! The visibility cache ([`crate::visibility::cache`]) keeps its records here; the
//! irradiance and importance caches will. Everything is generic over the records and
//! monomorphised, so the inner loops are the same machine code for every cache.
//!
//! ## Index
//! A bucket kd-tree of our own (module `tree`) over *distinct* positions, holding each
//! record's position, decoded normal and id inline in its leaf, 32 to a leaf, so that a
//! range query reads the records it finds in sequence. kiddo 5's mutable tree holds bare
//! ids, and fetching each found record's site from an id-indexed array was one cache miss
//! per record (records lie in insertion order, scattered in space). On the cache bench at
//! 100k records the tree alone looked up 1.1–1.5x faster than kiddo's at random and 1.1x
//! in pixel order; with its leaves scanned sixteen records at a time (AVX-512 masks and
//! compression) and the steps after it, lookups are 3–3.8x and 1.5–1.8x faster
//! (benches/README.md). Leaves split at the median of their widest coordinate, so records on a floor (one height for all) split as
//! well as any. Records that share a position exactly (a user inserting many normals at
//! one point) hang off the first in a chain, so no leaf fills with points no split can
//! separate. Removal happens only through [`SpatialIndex::rebuild`], which rebuilds the
//! tree balanced — the paper's "occasionally rebalance". Record ids are therefore dense and
//! stable between two rebuilds.
//!
//! ## Gathering and scoring
//! Chained records are read from the site array (position, decoded normal, chain link).
//! Lookups in pixel order go through a [`LookupScratch`] (module `scratch`): one range query
//! of twice the radius, centred ahead along the walk, serves the lookups whose balls it
//! covers. Each lookup filters the gathered records by distance and normal sixteen at a
//! time (module `gathered`; AVX-512 masks and compression where the CPU has them), with the
//! answer of a range query at its point bit for bit, and takes its `m` nearest by one
//! integer key (the [`Metric`], then id; module `candidates`): squared distance for CAM08,
//! survey eq. 6.3's distance plus normal term for the importance cache, one tree for both. Module `score` weights
//! them by eq. 9 ([`weight`]) one SIMD lane per record and picks the `n` heaviest. A wide
//! gathering prefetches the payloads of its records ([`Records::prefetch`]), which the
//! lookups it serves may compare.
//!
//! ## Reach
//! [`SpatialIndex::within_reach`] answers "which records cover `x`" (`|x − p_i| < R_i`),
//! in id order, for the irradiance cache's interpolation; the tree keeps per node a bound
//! on the reach of the records under it and enters only nodes that can reach `x` (module
//! [`reach`], which also holds the [`coverage`] test the caches share).
//!
//! ## Growing
//! [`waves::WaveBuilder`] grows any cache deterministically in waves (look up in
//! parallel, make the requested records in parallel, insert them in a fixed order), with
//! the cache's insertion test and record constructor plugged in ([`waves::WaveTarget`]).
//!
//! Module dependencies run one way: `gathered` ← `tree` ← `reach`, `candidates`, `score`
//! ← `scratch` ← `index`.

mod candidates;
mod gathered;
mod index;
pub mod metric;
pub mod reach;
mod score;
mod scratch;
mod tree;
pub mod waves;
pub mod weight;

pub use index::{prefetch, Records, SpatialIndex};
pub use metric::Metric;
pub use reach::{coverage, reach_factor};
pub(crate) use score::Hits;
pub use scratch::{with_thread_scratch, LookupScratch};
pub use weight::Weighting;

/// Largest `m` (records gathered per lookup): lookups keep them on the stack.
pub const MAX_NEAREST: usize = 64;

/// Largest `n` (heaviest records kept per lookup).
pub const MAX_KEEP: usize = 16;
