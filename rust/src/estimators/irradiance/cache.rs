//! The irradiance cache (Survey §3.2.3–3.3, Algorithms 1–3): records in the project's record
//! index ([`SpatialIndex`]), found by their reach, weighted by eq. 3.7 and interpolated with
//! their gradients by eq. 3.8.
//!
//! ## Weights and reach
//! A record `i` serves a point `p` (unit normal `n`) with
//!
//! `w_i(p) = 1/e_i − 1/a`,  `e_i = |p − p_i| / R_i + sqrt(1 − n·n_i)`   (eq. 3.7)
//!
//! where positive, that is where `e_i < a`. Since the normal term is `>= 0`, `w_i > 0`
//! implies `|p − p_i| < a·R_i`: the record's *reach*, which the index keeps per record
//! ([`Records::radius`]) so that a point query visits only the records that can serve it
//! (what Algorithm 3's multiply referenced octree buys). The weight is computed as
//! `(a − e)/(a·e)`, exactly 0 on the border `e = a`. A record lying in front of `p`
//! (Algorithm 2, line 3: `(p_i − p)·(n + n_i)/2` above [`FRONT_TOLERANCE`]` · a·R_i`) is
//! skipped: it sees a surface `p` does not. A record at exactly `p` with `n_i = n` has
//! `e = 0`, an infinite weight: the answer is then the mean of such records' `E`, so a
//! record's own point gets its `E` exactly.
//!
//! ## Interpolation (eq. 3.8)
//! `E(p) = Σ w_i E_i(p) / Σ w_i`, `E_i(p) = E_i + (n_i × n)·∇_r E_i + (p − p_i)·∇_t E_i`,
//! with the gradients [`Gradients`] selects, summed in record id order in `f64` (the same
//! bits for any thread count or tree shape). Channels the gradients push below 0 are
//! clamped to 0 and counted ([`Interpolated::clamped`]).
//!
//! ## Growing (Algorithm 1, two passes of §3.2.2)
//! [`IrradianceCache::build_from`] walks a G-buffer's pixels coarse to fine in waves
//! ([`WaveBuilder`], the visibility cache's build) and makes a record where no record is
//! usable (`Σ w_i = 0`); the renderer's samples then interpolate ([`IrradianceState::
//! interpolate`]). Radii are clamped to `[r_min, r_max]` pixel footprints of the point the
//! record is made for, so the record count does not depend on the scene's scale.
//!
//! ## Neighbour clamping (Křivánek et al. 2006, beyond the survey)
//! With [`IrradianceParams::clamp_neighbours`], inserting record `i` enforces
//! `R_i <= R_j + |p_i − p_j|` and `R_j <= R_i + |p_i − p_j|` for every record `j` that
//! reaches `p_i` or that `i` reaches: the triangle inequality of the distance to the
//! nearest surface, which `R` approximates. A record that saw far surfaces but sits next
//! to a small-radius neighbour (beside a wall, in a corner) cannot reach across it.

use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};

use glam::Vec3;

use super::record::{record_key, trace_record, IrradianceRecord, RecordParams, RecordRays};
use crate::error::{Error, Result};
use crate::estimators::direct::{DirectCounters, Lighting};
use crate::geometry::{Scene, TraversalCounters};
use crate::spatial::{Records, SpatialIndex};

/// Records whose point lies in front of the query point by more than this share of their
/// reach are skipped (Algorithm 2, line 3). Scale-free, unlike Ward's fixed distance.
pub const FRONT_TOLERANCE: f32 = 0.05;

/// `1 − cos` below which two unit normals count as equal in eq. 3.7 (normal term 0): the
/// rounding of `f32` unit vectors, a turn of at most 0.06°.
pub const SAME_NORMAL_COS: f64 = 4.0 * f32::EPSILON as f64;

/// Most strata per record (`M·N`).
pub const MAX_STRATA: u32 = 1 << 16;
/// Most direct-light samples per stratum hit.
pub const MAX_SECONDARY_SPP: u32 = 1024;

/// Which gradients interpolation applies (eq. 3.8).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Gradients {
    /// `E_i` alone.
    None,
    /// `E_i` and the rotational term.
    Rotation,
    /// Both terms (Ward & Heckbert 1992).
    #[default]
    Both,
}

impl Gradients {
    /// Every choice, in the order the errors list them.
    pub const ALL: [Gradients; 3] = [Gradients::None, Gradients::Rotation, Gradients::Both];

    /// The name Python uses: "none", "rotation" or "both".
    pub const fn name(self) -> &'static str {
        match self {
            Gradients::None => "none",
            Gradients::Rotation => "rotation",
            Gradients::Both => "both",
        }
    }

    /// The choice called `name`; an error naming `gradients` otherwise.
    pub fn parse(name: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|g| g.name() == name)
            .ok_or_else(|| {
                Error::invalid(
                    "gradients",
                    format!("expected one of \"none\", \"rotation\", \"both\", got {name:?}"),
                )
            })
    }

    fn rotation(self) -> bool {
        self != Gradients::None
    }

    fn translation(self) -> bool {
        self == Gradients::Both
    }
}

/// Parameters of an irradiance cache.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IrradianceParams {
    /// `a` of eq. 3.7, in `(0, 1]`: a record serves points within `a·R_i` (and normals within
    /// `acos(1 − a²)`). Smaller: more records, less bias.
    pub a: f32,
    /// Strata in `θ` (`M`) and `φ` (`N`) per record, `M·N <= MAX_STRATA`.
    pub strata: (u32, u32),
    /// Least `R_i`, pixel footprints at the record (finite, `> 0`).
    pub r_min: f32,
    /// Most `R_i`, pixel footprints at the record (finite, `>= r_min`).
    pub r_max: f32,
    /// Gradients interpolation applies.
    pub gradients: Gradients,
    /// Neighbour clamping of radii on insertion (module docs).
    pub clamp_neighbours: bool,
    /// Direct-light samples at each stratum's hit, `1..=MAX_SECONDARY_SPP`.
    pub secondary_spp: u32,
}

impl IrradianceParams {
    /// `a = 0.2`, 16 x 64 strata, radii in 1.5–32 footprints, both gradients, neighbour
    /// clamping, one direct sample per stratum.
    pub const DEFAULT: Self = Self {
        a: 0.2,
        strata: (16, 64),
        r_min: 1.5,
        r_max: 32.0,
        gradients: Gradients::Both,
        clamp_neighbours: true,
        secondary_spp: 1,
    };

    /// Checks every range; the error names the parameter.
    pub fn validate(&self) -> Result<()> {
        if !(self.a > 0.0 && self.a <= 1.0) {
            return Err(Error::invalid(
                "a",
                format!("must lie in (0, 1], got {}", self.a),
            ));
        }
        let (m, n) = self.strata;
        if m == 0 || n == 0 || m as u64 * n as u64 > MAX_STRATA as u64 {
            return Err(Error::invalid(
                "strata",
                format!("must be two counts >= 1 with a product <= {MAX_STRATA}, got ({m}, {n})"),
            ));
        }
        if !(self.r_min.is_finite() && self.r_min > 0.0) {
            return Err(Error::invalid(
                "r_min",
                format!("must be finite and > 0, got {}", self.r_min),
            ));
        }
        if !(self.r_max.is_finite() && self.r_max >= self.r_min) {
            return Err(Error::invalid(
                "r_max",
                format!(
                    "must be finite and >= r_min ({}), got {}",
                    self.r_min, self.r_max
                ),
            ));
        }
        crate::error::check_range("secondary_spp", self.secondary_spp, 1, MAX_SECONDARY_SPP)
    }

    /// How records are traced.
    pub fn record(&self) -> RecordParams {
        RecordParams {
            strata: self.strata,
            secondary_spp: self.secondary_spp,
        }
    }

    /// `R_i`'s bounds, world units, for a point of pixel footprint `footprint`.
    pub fn radius_bounds(&self, footprint: f32) -> (f32, f32) {
        (self.r_min * footprint, self.r_max * footprint)
    }
}

impl Default for IrradianceParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The records as the index reads them: reach `a·R_i` (module docs).
#[derive(Clone, Debug, Default)]
pub struct RecordSet {
    records: Vec<IrradianceRecord>,
    /// `a`, widened by a part in 10⁶ so that the reach in `f32` covers every point with
    /// `e < a` computed in `f64`.
    reach_scale: f32,
}

impl RecordSet {
    fn new(a: f32) -> Self {
        Self {
            records: Vec::new(),
            reach_scale: a * (1.0 + 1e-6),
        }
    }

    /// The records, by id.
    pub fn as_slice(&self) -> &[IrradianceRecord] {
        &self.records
    }
}

impl Records for RecordSet {
    fn len(&self) -> usize {
        self.records.len()
    }

    fn site(&self, id: usize) -> (Vec3, Vec3) {
        let r = &self.records[id];
        (r.position, r.normal)
    }

    fn radius(&self, id: usize) -> f32 {
        self.reach_scale * self.records[id].radius
    }
}

/// What [`IrradianceState::interpolate`] found at a point.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Interpolated {
    /// Interpolated irradiance (eq. 3.8), W/m² per channel, `>= 0`.
    pub irradiance: [f32; 3],
    /// `Σ w_i` (`+inf` when a record sits exactly at the point).
    pub weight_sum: f64,
    /// Records used.
    pub records: u32,
    /// Channels clamped at 0 after the gradients pushed them below.
    pub clamped: u32,
}

/// Totals of a cache since its creation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct IrradianceCounters {
    /// Records made and inserted.
    pub records_inserted: u64,
    /// Records made but not inserted (a record of the same wave served the point).
    pub records_discarded: u64,
    /// Hemisphere rays of records (discarded ones included).
    pub hemisphere_rays: u64,
    /// Rays of the direct estimates at the hemisphere hits.
    pub secondary_rays: u64,
    /// Radii lowered by neighbour clamping.
    pub clamped_radii: u64,
}

impl IrradianceCounters {
    fn count(&mut self, rays: &RecordRays) {
        self.hemisphere_rays += rays.hemisphere;
        self.secondary_rays += rays.secondary;
    }
}

/// The records and their index, behind the cache's lock.
#[derive(Clone, Debug)]
pub struct IrradianceState {
    index: SpatialIndex<RecordSet>,
    /// Geometry fingerprint of the scene the records describe.
    pub(super) scene: Option<u64>,
    /// Median pixel footprint of the last build (world units): the footprint of a record
    /// inserted without one.
    pub(super) default_footprint: Option<f32>,
    pub(super) counters: IrradianceCounters,
    a: f64,
    gradients: Gradients,
}

impl IrradianceState {
    fn new(params: &IrradianceParams) -> Self {
        Self {
            index: SpatialIndex::new(RecordSet::new(params.a)),
            scene: None,
            default_footprint: None,
            counters: IrradianceCounters::default(),
            a: params.a as f64,
            gradients: params.gradients,
        }
    }

    /// Number of records.
    pub fn len(&self) -> usize {
        self.index.len()
    }

    /// True without records.
    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// The records, by id.
    pub fn records(&self) -> &[IrradianceRecord] {
        self.index.records().as_slice()
    }

    /// Bytes of the records and of their index.
    pub fn memory_bytes(&self) -> usize {
        self.index.records().records.capacity() * std::mem::size_of::<IrradianceRecord>()
            + self.index.memory_bytes()
    }

    /// Appends to `out` the records that can serve `x` (reach covers it), `(id, |x − p_i|²)`
    /// in id order.
    fn reaching(&self, x: Vec3, out: &mut Vec<(u32, f32)>) {
        out.clear();
        self.index.within_reach(x, out);
    }

    /// Eq. 3.7 for record `r` at `x` (unit `n`): the weight where the record is usable
    /// (`+inf` at its own point and normal), `None` elsewhere or when it lies in front.
    pub fn weight(&self, r: &IrradianceRecord, x: Vec3, n: Vec3) -> Option<f64> {
        let a = self.a;
        let d = (x - r.position).length() as f64;
        let cos = (n.dot(r.normal) as f64).clamp(-1.0, 1.0);
        // Unit normals in f32 are unit to a few ulps, so equal normals may give
        // `cos = 1 − 1e-7`, whose root (3e-4) would keep a record's own point from `e = 0`.
        let turn = if cos >= 1.0 - SAME_NORMAL_COS {
            0.0
        } else {
            (1.0 - cos).sqrt()
        };
        let e = d / r.radius as f64 + turn;
        if e >= a || e.is_nan() {
            return None;
        }
        let front = (r.position - x).dot((n + r.normal) * 0.5);
        if front > FRONT_TOLERANCE * self.a as f32 * r.radius {
            return None;
        }
        Some(if e == 0.0 {
            f64::INFINITY
        } else {
            (a - e) / (a * e)
        })
    }

    /// Whether some record is usable at `x` (unit `n`): Algorithm 1, line 3.
    pub fn covers(&self, x: Vec3, n: Vec3, scratch: &mut Vec<(u32, f32)>) -> bool {
        self.reaching(x, scratch);
        let records = self.records();
        scratch
            .iter()
            .any(|&(id, _)| self.weight(&records[id as usize], x, n).is_some())
    }

    /// Eq. 3.8 at `x` (unit `n`): `None` where no record is usable. `scratch` is reused
    /// between calls.
    pub fn interpolate(
        &self,
        x: Vec3,
        n: Vec3,
        scratch: &mut Vec<(u32, f32)>,
    ) -> Option<Interpolated> {
        self.reaching(x, scratch);
        let records = self.records();
        let (rotation, translation) = (self.gradients.rotation(), self.gradients.translation());
        let mut sum = [0.0f64; 3];
        let mut total = 0.0f64;
        let mut used = 0u32;
        // Records at the point itself (infinite weight) decide alone.
        let mut exact = [0.0f64; 3];
        let mut exact_count = 0u32;
        for &(id, _) in scratch.iter() {
            let r = &records[id as usize];
            let Some(w) = self.weight(r, x, n) else {
                continue;
            };
            used += 1;
            if w.is_infinite() {
                for (c, e) in exact.iter_mut().enumerate() {
                    *e += r.irradiance[c] as f64;
                }
                exact_count += 1;
                continue;
            }
            let turn = r.normal.cross(n);
            let step = x - r.position;
            for (c, s) in sum.iter_mut().enumerate() {
                let mut e = r.irradiance[c] as f64;
                if rotation {
                    e += turn.dot(r.rotation[c]) as f64;
                }
                if translation {
                    e += step.dot(r.translation[c]) as f64;
                }
                *s += w * e;
            }
            total += w;
        }
        if used == 0 {
            return None;
        }
        let (values, weight_sum) = if exact_count > 0 {
            (exact.map(|e| e / exact_count as f64), f64::INFINITY)
        } else {
            (sum.map(|s| s / total), total)
        };
        let mut clamped = 0;
        let irradiance = values.map(|v| {
            if v < 0.0 {
                clamped += 1;
                0.0
            } else {
                v as f32
            }
        });
        Some(Interpolated {
            irradiance,
            weight_sum,
            records: used,
            clamped,
        })
    }

    /// Inserts `record` (finite position, unit normal, radius finite and `> 0`) with
    /// neighbour clamping when `clamp` (module docs); returns its id.
    pub fn push(&mut self, mut record: IrradianceRecord, clamp: bool) -> Result<u32> {
        if clamp && !self.is_empty() {
            let reach = self.a as f32 * record.radius;
            let mut near = Vec::new();
            self.reaching(record.position, &mut near);
            let mut reached = Vec::new();
            self.index
                .within_radius(record.position, reach, &mut reached);
            near.extend(reached);
            near.sort_unstable_by_key(|&(id, _)| id);
            near.dedup_by_key(|&mut (id, _)| id);
            let records = self.index.records().as_slice();
            // The new radius first, from the neighbours as they were; then theirs from it.
            let bound = near
                .iter()
                .map(|&(id, d2)| records[id as usize].radius + d2.sqrt())
                .fold(record.radius, f32::min);
            if bound < record.radius {
                record.radius = bound;
                self.counters.clamped_radii += 1;
            }
            let records = &mut self.index.records_mut().records;
            for &(id, d2) in &near {
                let bound = record.radius + d2.sqrt();
                let r = &mut records[id as usize].radius;
                if bound < *r {
                    *r = bound;
                    self.counters.clamped_radii += 1;
                }
            }
        }
        let id = self.index.admit(|set| {
            set.records.push(record);
            Ok(set.records.len() - 1)
        })?;
        self.counters.records_inserted += 1;
        Ok(id)
    }

    /// Tightens the index's reach bounds after neighbour clamping lowered radii (answers are
    /// exact either way; loose bounds only prune less).
    pub fn refresh_reach(&mut self) {
        self.index.refresh_reach();
    }

    /// The totals since creation.
    pub fn counters(&self) -> IrradianceCounters {
        self.counters
    }

    /// Replaces the records by `records` (loaded: radii as saved, no clamping).
    pub(super) fn restore(&mut self, records: Vec<IrradianceRecord>) {
        self.index.rebuild(|set| set.records = records);
    }
}

/// An irradiance cache: parameters and records behind a lock, bound to one scene's
/// geometry.
#[derive(Debug)]
pub struct IrradianceCache {
    params: IrradianceParams,
    state: RwLock<IrradianceState>,
}

impl Clone for IrradianceCache {
    fn clone(&self) -> Self {
        Self {
            params: self.params,
            state: RwLock::new(self.read().clone()),
        }
    }
}

impl IrradianceCache {
    /// An empty cache; fails naming the first parameter out of range.
    pub fn new(params: IrradianceParams) -> Result<Self> {
        params.validate()?;
        Ok(Self {
            params,
            state: RwLock::new(IrradianceState::new(&params)),
        })
    }

    /// An empty cache with `params` and the state `make` fills in (loading).
    pub(super) fn with_state(
        params: IrradianceParams,
        fill: impl FnOnce(&mut IrradianceState) -> Result<()>,
    ) -> Result<Self> {
        let cache = Self::new(params)?;
        fill(&mut cache.write())?;
        Ok(cache)
    }

    /// The parameters.
    pub fn params(&self) -> &IrradianceParams {
        &self.params
    }

    /// The state under a shared lock.
    pub fn read(&self) -> RwLockReadGuard<'_, IrradianceState> {
        self.state.read().unwrap_or_else(|e| e.into_inner())
    }

    /// The state under an exclusive lock.
    pub(crate) fn write(&self) -> RwLockWriteGuard<'_, IrradianceState> {
        self.state.write().unwrap_or_else(|e| e.into_inner())
    }

    /// Number of records.
    pub fn len(&self) -> usize {
        self.read().len()
    }

    /// True without records.
    pub fn is_empty(&self) -> bool {
        self.read().is_empty()
    }

    /// Bytes of one record (the payload alone: position, normal, `E`, `R_i`, gradients).
    pub const fn record_bytes() -> usize {
        std::mem::size_of::<IrradianceRecord>()
    }

    /// Bytes of records and index.
    pub fn memory_bytes(&self) -> usize {
        self.read().memory_bytes()
    }

    /// The totals since creation.
    pub fn counters(&self) -> IrradianceCounters {
        self.read().counters
    }

    /// The fingerprint of the scene the records describe, if bound.
    pub fn scene_fingerprint(&self) -> Option<u64> {
        self.read().scene
    }

    /// The median pixel footprint of the last build, world units.
    pub fn default_footprint(&self) -> Option<f32> {
        self.read().default_footprint
    }

    /// Binds the cache to `scene`'s geometry on first use; refuses another scene with an
    /// error naming `cache`, and stays as it was.
    pub fn bind_scene(&self, scene: &Scene) -> Result<()> {
        let f = scene.geometry_fingerprint();
        let mut state = self.write();
        match state.scene {
            Some(bound) if bound != f => Err(Error::invalid(
                "cache",
                crate::visibility::cache::other_scene(bound, f),
            )),
            _ => {
                state.scene = Some(f);
                Ok(())
            }
        }
    }

    /// Traces the record of the surface point `position` (unit `normal`) for a pixel of
    /// `footprint` world units (its radius bounds), its random numbers from `(seed, key)`.
    /// Takes no lock.
    pub fn trace(
        &self,
        lighting: &Lighting,
        (position, normal, footprint): (Vec3, Vec3, f32),
        seed: u64,
        key: u64,
    ) -> (IrradianceRecord, RecordRays, TraversalCounters) {
        let mut counters = DirectCounters::default();
        let mut bvh = TraversalCounters::default();
        let (record, rays) = trace_record(
            lighting,
            position,
            normal,
            &self.params.record(),
            self.params.radius_bounds(footprint),
            seed,
            key,
            &mut counters,
            &mut bvh,
        );
        (record, rays, bvh)
    }

    /// Traces and inserts a record at `position` (`normal` need not be unit) whatever the
    /// records near it; `footprint` (world units) sets its radius bounds, `None`: the last
    /// build's median. Returns its id. The cache is unchanged on error.
    pub fn insert(
        &self,
        lighting: &Lighting,
        position: Vec3,
        normal: Vec3,
        footprint: Option<f32>,
        seed: u64,
    ) -> Result<u32> {
        check_point("point", position)?;
        let normal = unit_normal("normal", normal)?;
        let footprint = match footprint.or(self.default_footprint()) {
            Some(f) if f.is_finite() && f > 0.0 => f,
            Some(f) => {
                return Err(Error::invalid(
                    "footprint",
                    format!("must be finite and > 0, got {f}"),
                ))
            }
            None => {
                return Err(Error::invalid(
                    "footprint",
                    "the cache has not been built, so a record's pixel footprint (world \
                     units) must be given",
                ))
            }
        };
        self.bind_scene(lighting.scene)?;
        let key = record_key(position, normal);
        let (record, rays, bvh) = self.trace(lighting, (position, normal, footprint), seed, key);
        lighting.scene.add_counters(bvh);
        let mut state = self.write();
        state.counters.count(&rays);
        state.push(record, self.params.clamp_neighbours)
    }
}

/// Ids of the records an interpolation used, in id order.
pub type UsedRecords = Vec<u32>;

impl IrradianceCache {
    /// Eq. 3.8 at every point (unit `normals`), in parallel on `threads` workers: `None`
    /// where no record is usable. The same answers for any `threads`.
    pub fn interpolate_batch(
        &self,
        points: &[Vec3],
        normals: &[Vec3],
        threads: Option<usize>,
    ) -> Result<Vec<Option<(Interpolated, UsedRecords)>>> {
        use rayon::prelude::*;
        if normals.len() != points.len() {
            return Err(Error::invalid(
                "normals",
                format!(
                    "expected {} like points, got {}",
                    points.len(),
                    normals.len()
                ),
            ));
        }
        let state = self.read();
        crate::parallel::with_threads(threads, || {
            points
                .par_iter()
                .zip(normals)
                .with_min_len(256)
                .map_init(Vec::new, |scratch, (&x, &n)| {
                    let found = state.interpolate(x, n, scratch)?;
                    // The records it used: those usable, in id order.
                    let records = state.records();
                    let ids = scratch
                        .iter()
                        .filter(|&&(id, _)| state.weight(&records[id as usize], x, n).is_some())
                        .map(|&(id, _)| id)
                        .collect();
                    Some((found, ids))
                })
                .collect()
        })
    }
}

impl IrradianceCache {
    /// Inserts a record made elsewhere (a copy, a synthetic one) with neighbour clamping
    /// when the parameters ask for it; returns its id. Refused, naming `record`, unless its
    /// position is finite, its normal unit, its radius finite and `> 0`, its irradiance
    /// finite and `>= 0` and its gradients finite; the cache is then unchanged.
    pub fn insert_record(&self, record: IrradianceRecord) -> Result<u32> {
        super::io::check_record(&record).map_err(|why| Error::invalid("record", why))?;
        self.write().push(record, self.params.clamp_neighbours)
    }
}

/// Fails naming `name` unless `p` is finite.
pub(crate) fn check_point(name: &str, p: Vec3) -> Result<()> {
    if p.is_finite() {
        Ok(())
    } else {
        Err(Error::invalid(name, format!("must be finite, got {p}")))
    }
}

/// `n` made unit; fails naming `name` when it is not finite or has no direction.
pub(crate) fn unit_normal(name: &str, n: Vec3) -> Result<Vec3> {
    let length = n.length();
    if n.is_finite() && length > 1e-12 && length.is_finite() {
        Ok(n / length)
    } else {
        Err(Error::invalid(
            name,
            format!("must be a finite non-zero vector, got {n}"),
        ))
    }
}

#[cfg(test)]
mod tests;
