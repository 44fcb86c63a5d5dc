//! Visibility caching (Clarberg & Akenine-Möller 2008, "CAM08", §5 and §6.1).
//!
//! [`record`]: the cache records. A record is the world-space visibility of the whole
//! sphere at one surface point, one bit per texel of a `2^M x 2^M` equal-area octahedral
//! grid in Morton order (CAM08 §5.5, eq. 10), with a 2-bit empty / partial / full code per
//! quadtree node above the bits (Fig. 9), the mean difference of two maps by xor and
//! popcount (eq. 11), the record's ambient occlusion (eq. 12) and its nearest hit distance
//! `R_i` (§6.1). The directions come from [`crate::sampling::pattern`].
//!
//! [`cache`]: the records in the crate's spatial index ([`crate::spatial`]) with eq. 9
//! weighted lookups, §5.2's insertion criteria, a deterministic build in waves, and
//! eviction over frames (§5.3); [`params`]: Table 1's parameters with low / medium / high
//! presets (§5.4).
//!
//! [`correlation`]: CAM08 §4.1's measurement of how visibility correlates between surface
//! points, `ρ̄(d, θ)` by distance and normal difference (Figs. 3–4).

pub mod cache;
pub mod correlation;
pub mod params;
pub mod record;

pub use cache::{
    BuildReport, CacheCounters, EvictionReport, Lookup, LookupScratch, Neighbour, VisibilityCache,
};
pub use params::CacheParams;
pub use record::{
    bytes_per_record, Coverage, Node, NodeIter, Record, RecordHeader, RecordRays, RecordStore,
    RecordTracing, VisibilityBits, VisibilityView,
};
