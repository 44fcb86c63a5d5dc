//! The importance cache's records (survey ch. 6, Algorithm 12, Fig. 6.4): at sparse
//! camera-visible points, every light's contribution in three rows, kept in the project's
//! record index ([`SpatialIndex`]) and found by eq. 6.3.
//!
//! ## A record
//! At the surface point `x` (unit normal `n`, the diffuse part `ρ_d/π` of its material as
//! `f_s`, so the record holds for any view), for light `k` ([`Vpl::connect`], any kind):
//!
//! - F: `L f_s G V`, the light's term with its visibility, the record's rays to every
//!   light traced as one batch from `x` (runs from one origin: packets);
//! - U: `L f_s G`, the same without visibility;
//! - B: `L f_s G_max`, with [`super::bound`]'s `G_max` over the record's region: the ball of
//!   [`ImportanceRecord::radius`] about `x` and normals within [`REGION_CONE`] of `n`.
//!   For an oriented point light `L f_s` is `luminance(ρ_d/π · Φ f_v)` with the light's
//!   own `f_v` when it does not depend on direction ([`Vpl::diffuse_intensity`]), else
//!   `Φ/π` (a glossy surface VPL: not a bound, only a shape); for a map direction `f_s Φ /
//!   disk area` times the cosine bound. A light inside the ball (unbounded `G_max`) takes
//!   `G_max = 1 / (r/4)²`, and B is never below U at the record itself.
//!
//! Luminances, stored as running sums (CDFs) in `f32` ([`RowCdf`]): 4 bytes per light and
//! row, or, where fewer than half the lights have mass (occluded for F, behind the record
//! for U and B), 8 bytes per light of non-zero mass (its index and sum), the same pmf
//! either way; at most 12 bytes per light and record.
//!
//! ## Region and reach
//! A record made for a pixel of footprint `f` (world units) reaches `R = REACH · spacing · f`:
//! a grid record's neighbours lie about `spacing · f` apart on a surface facing the camera,
//! so a point sees about seven records within reach there, fewer at edges and silhouettes.
//! Its region (row B) is the same ball.
//!
//! ## Lookup (eq. 6.3)
//! A shading point `x` with unit normal `n` draws from the `nearest` records under
//! `|x − p_i| + λ √(1 − n · n_i)` (the index's `m`-nearest query with
//! [`Metric::DistanceNormal`]) among those within the largest reach of the cache and whose
//! normals lie within [`REGION_CONE`] of `n`; `λ` is `lam` times the median reach, so the
//! choice does not change with the scene's scale. None there: row C alone.

use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};

use glam::Vec3;

use super::combine::{CdfView, Matrix, Row};
use crate::error::{Error, Result};
use crate::lights::vpl::{luminance, Vpl, VplKind, VplSet};
use crate::spatial::{with_thread_scratch, Metric, Records, SpatialIndex, Weighting};

/// The normal cone of a record's region and of its lookups, radians: records whose normal
/// differs more are not looked up, and row B bounds over normals within it.
pub const REGION_CONE: f32 = std::f32::consts::FRAC_PI_4;

/// A record's reach and region radius, in grid spacings of its pixel's footprint.
pub const REACH: f32 = 1.5;

/// Most `nearest` (records a lookup combines).
pub const MAX_NEAREST: u32 = crate::spatial::MAX_NEAREST as u32;

/// Most grid spacing, pixels.
pub const MAX_SPACING: u32 = 1 << 12;

/// Parameters of an importance cache.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImportanceParams {
    /// Pixels between grid records, `1..=MAX_SPACING`.
    pub spacing: u32,
    /// Records a lookup combines, `1..=MAX_NEAREST`; points with fewer within reach get a
    /// record of their own.
    pub nearest: u32,
    /// `λ` of eq. 6.3 in median reaches (finite, `>= 0`).
    pub lam: f32,
    /// `(α_F, α_U, α_B, α_C)` of eq. 6.6, each in `(0, 1]`: the renders' default.
    pub alpha: [f64; 4],
}

impl ImportanceParams {
    /// Spacing 8, 3 nearest, `λ` one median reach, `α = (0.5, 0.5, 0.5, 0.3)`.
    ///
    /// `α_C` below 1 lets F own a light whose cached probability is under the uniform
    /// `1/N` (down to `0.3/N`) rather than hand it to C's uniform draws. Relative MSE
    /// against the exact sum at 8 draws per row and 8 samples per pixel centre (96x72 to
    /// 128x96, 2,000 lights), `α_C` = 1 / 0.3 / 0.1: cornell 1.7e-3 / 9.6e-4 / 9.7e-4,
    /// garage `ceiling_lights` (1,000 area lights and 1,000 VPLs) 0.078 / 0.058 / 0.059,
    /// garden 6.4e-3 / 7.4e-3 / 7.5e-3; `α_F = α_U = α_B` in {0.2, 0.5, 1} moved cornell
    /// by under 3%.
    pub const DEFAULT: Self = Self {
        spacing: 8,
        nearest: 3,
        lam: 1.0,
        alpha: [0.5, 0.5, 0.5, 0.3],
    };

    /// Checks every range; the error names the parameter.
    pub fn validate(&self) -> Result<()> {
        crate::error::check_range("spacing", self.spacing, 1, MAX_SPACING)?;
        crate::error::check_range("nearest", self.nearest, 1, MAX_NEAREST)?;
        if !(self.lam.is_finite() && self.lam >= 0.0) {
            return Err(Error::invalid(
                "lam",
                format!("must be finite and >= 0, got {}", self.lam),
            ));
        }
        super::combine::Combine::AlphaMax(self.alpha).validate()
    }
}

impl Default for ImportanceParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// One row of a record: the running sums of its lights' luminances (module docs).
///
/// Invariants: sums finite and non-decreasing; a dense row has one per light of the
/// cache's set, a sparse row one per light of positive value, lights ascending.
#[derive(Clone, Debug, PartialEq)]
pub enum RowCdf {
    /// `sums[k]`: lights `0..=k`.
    Dense(Box<[f32]>),
    /// `sums[i]`: lights `lights[..=i]`; every other light is 0.
    Sparse {
        lights: Box<[u32]>,
        sums: Box<[f32]>,
    },
}

impl RowCdf {
    /// The row of `values` (one per light; non-finite and negative ones count as 0), summed
    /// in `f64` and stored in `f32`: sparse when under half the lights have a positive
    /// value (fewer bytes), dense otherwise; both give each light the same mass.
    pub fn from_values(values: &[f64]) -> Self {
        let positive = |x: f64| x.is_finite() && x > 0.0;
        let nonzero = values.iter().filter(|&&x| positive(x)).count();
        let mut total = 0.0f64;
        if 2 * nonzero < values.len() {
            let (mut lights, mut sums) = (Vec::with_capacity(nonzero), Vec::with_capacity(nonzero));
            for (k, &x) in values.iter().enumerate().filter(|(_, &x)| positive(x)) {
                total += x;
                lights.push(k as u32);
                sums.push(total as f32);
            }
            RowCdf::Sparse {
                lights: lights.into_boxed_slice(),
                sums: sums.into_boxed_slice(),
            }
        } else {
            let sums = values.iter().map(|&x| {
                total += if positive(x) { x } else { 0.0 };
                total as f32
            });
            RowCdf::Dense(sums.collect())
        }
    }

    /// The row as the distribution matrix reads it.
    pub fn view(&self) -> CdfView<'_, f32> {
        match self {
            RowCdf::Dense(sums) => CdfView::dense(sums),
            RowCdf::Sparse { lights, sums } => CdfView::sparse(lights, sums),
        }
    }

    /// Light `k`'s value.
    pub fn value(&self, k: usize) -> f32 {
        self.view().entry(k) as f32
    }

    /// The row's total.
    pub fn total(&self) -> f32 {
        self.view().total() as f32
    }

    /// The row's running sums over all `lights` lights (dense form).
    pub fn dense(&self, lights: usize) -> Vec<f32> {
        match self {
            RowCdf::Dense(sums) => sums.to_vec(),
            RowCdf::Sparse { lights: l, sums } => {
                let mut out = vec![0.0f32; lights];
                let (mut at, mut sum) = (0, 0.0f32);
                for (k, o) in out.iter_mut().enumerate() {
                    if l.get(at) == Some(&(k as u32)) {
                        sum = sums[at];
                        at += 1;
                    }
                    *o = sum;
                }
                out
            }
        }
    }

    /// Whether every stored sum is finite.
    pub fn is_finite(&self) -> bool {
        match self {
            RowCdf::Dense(s) | RowCdf::Sparse { sums: s, .. } => s.iter().all(|x| x.is_finite()),
        }
    }

    /// Bytes its sums (and lights) take.
    pub fn bytes(&self) -> usize {
        match self {
            RowCdf::Dense(s) => 4 * s.len(),
            RowCdf::Sparse { lights, sums } => 4 * (lights.len() + sums.len()),
        }
    }
}

/// One record (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct ImportanceRecord {
    /// The surface point (not offset), world units.
    pub position: Vec3,
    /// Unit normal, on the camera's side.
    pub normal: Vec3,
    /// Reach and region radius, world units (`> 0`).
    pub radius: f32,
    /// Rows F, U, B.
    pub rows: [RowCdf; 3],
}

impl ImportanceRecord {
    /// Row `row` (F, U or B).
    pub fn row(&self, row: Row) -> &RowCdf {
        &self.rows[row as usize]
    }

    /// Light `k`'s value in row `row`.
    pub fn value(&self, row: Row, k: usize) -> f32 {
        self.row(row).value(k)
    }
}

/// The records as the index reads them.
#[derive(Clone, Debug, Default)]
pub struct RecordSet {
    pub records: Vec<ImportanceRecord>,
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
        self.records[id].radius
    }
}

/// What the lock guards: the records in their index, and the largest and median reach.
#[derive(Clone, Debug)]
pub struct ImportanceState {
    pub index: SpatialIndex<RecordSet>,
    /// Largest record reach (0 without records).
    pub max_radius: f32,
}

/// The importance cache: its light set (the lights every record's rows are over, in
/// order), its parameters and its records.
#[derive(Debug)]
pub struct ImportanceCache {
    params: ImportanceParams,
    /// The lights, as given.
    pub lights: Vec<Vpl>,
    /// The set's disk area (map directions' irradiance).
    pub disk_area: f32,
    /// The geometry fingerprint of the scene the lights were traced in.
    pub scene: u64,
    state: RwLock<ImportanceState>,
}

impl Clone for ImportanceCache {
    fn clone(&self) -> Self {
        Self {
            params: self.params,
            lights: self.lights.clone(),
            disk_area: self.disk_area,
            scene: self.scene,
            state: RwLock::new(self.read().clone()),
        }
    }
}

impl ImportanceCache {
    /// An empty cache over `lights` with `params`; errors name `lights` (an empty set) or
    /// the parameter out of range.
    pub fn new(lights: &VplSet, params: ImportanceParams) -> Result<Self> {
        params.validate()?;
        if lights.vpls.is_empty() {
            return Err(Error::invalid("lights", "the light set is empty"));
        }
        Ok(Self {
            params,
            lights: lights.vpls.clone(),
            disk_area: lights.disk_area,
            scene: lights.fingerprint,
            state: RwLock::new(ImportanceState {
                index: SpatialIndex::new(RecordSet::default()),
                max_radius: 0.0,
            }),
        })
    }

    /// Its parameters.
    pub fn params(&self) -> &ImportanceParams {
        &self.params
    }

    /// Sets `α` (each in `(0, 1]`), the renders' default; an error naming `alpha` leaves
    /// it unchanged.
    pub fn set_alpha(&mut self, alpha: [f64; 4]) -> Result<()> {
        super::combine::Combine::AlphaMax(alpha).validate()?;
        self.params.alpha = alpha;
        Ok(())
    }

    /// The state under a shared lock.
    pub fn read(&self) -> RwLockReadGuard<'_, ImportanceState> {
        self.state.read().unwrap_or_else(|e| e.into_inner())
    }

    /// The state under an exclusive lock.
    pub fn write(&self) -> RwLockWriteGuard<'_, ImportanceState> {
        self.state.write().unwrap_or_else(|e| e.into_inner())
    }

    /// Records held.
    pub fn len(&self) -> usize {
        self.read().index.len()
    }

    /// True without records.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Fails, naming `cache`, unless `scene` has the geometry the lights were traced in.
    pub fn check_scene(&self, scene: &crate::geometry::Scene) -> Result<()> {
        if scene.geometry_fingerprint() != self.scene {
            return Err(Error::invalid(
                "cache",
                "its lights were traced in other geometry: build a cache for this scene",
            ));
        }
        Ok(())
    }

    /// Bytes of the records' rows alone (at most 12 per light and record).
    pub fn row_bytes(&self) -> usize {
        let state = self.read();
        let records = &state.index.records().records;
        records
            .iter()
            .flat_map(|r| r.rows.iter().map(RowCdf::bytes))
            .sum()
    }

    /// Bytes of the records' rows (at most 12 per light and record) and their index.
    pub fn memory_bytes(&self) -> usize {
        let state = self.read();
        let rows: usize = state
            .index
            .records()
            .records
            .iter()
            .map(|r| {
                r.rows.iter().map(RowCdf::bytes).sum::<usize>()
                    + std::mem::size_of::<ImportanceRecord>()
            })
            .sum();
        rows + state.index.memory_bytes()
    }

    /// `λ` of eq. 6.3 in world units: `lam` times the median reach (0 without records).
    pub fn lambda_world(state: &ImportanceState, lam: f32) -> f32 {
        let mut r: Vec<f32> = state
            .index
            .records()
            .records
            .iter()
            .map(|r| r.radius)
            .collect();
        if r.is_empty() {
            return 0.0;
        }
        let mid = r.len() / 2;
        let (_, m, _) = r.select_nth_unstable_by(mid, f32::total_cmp);
        lam * *m
    }
}

/// A lookup's answer: the ids of the records a shading point draws from, in id order.
#[derive(Clone, Copy, Debug)]
pub struct Nearest {
    pub ids: [u32; crate::spatial::MAX_NEAREST],
    pub len: usize,
}

impl Default for Nearest {
    fn default() -> Self {
        Self {
            ids: [0; crate::spatial::MAX_NEAREST],
            len: 0,
        }
    }
}

impl Nearest {
    /// The ids.
    pub fn ids(&self) -> &[u32] {
        &self.ids[..self.len]
    }
}

impl ImportanceState {
    /// Eq. 6.3's `nearest` records at `x` (unit normal `n`), `λ` in world units (module
    /// docs), in id order.
    pub fn nearest(&self, x: Vec3, n: Vec3, nearest: u32, lambda: f32) -> Nearest {
        let mut out = Nearest::default();
        if self.index.is_empty() || !(x.is_finite() && n.is_finite()) {
            return out;
        }
        let weighting = Weighting {
            m: (nearest as usize).clamp(1, crate::spatial::MAX_NEAREST),
            theta_max: REGION_CONE,
            w_lo: 0.0,
            lambda: 0.0,
            metric: Metric::DistanceNormal { lambda },
        };
        with_thread_scratch(|scratch| {
            let hits = self
                .index
                .m_nearest(&weighting, x, n, self.max_radius, scratch);
            for i in 0..hits.len {
                out.ids[i] = hits.id(i);
            }
            out.len = hits.len;
        });
        out.ids[..out.len].sort_unstable();
        out
    }

    /// The distribution matrix of the records `ids` over `lights` lights.
    pub fn matrix<'a>(&'a self, ids: &[u32], lights: usize) -> Result<Matrix<'a, f32>> {
        let mut m = Matrix::new(lights)?;
        let records = &self.index.records().records;
        for &id in ids {
            let r = &records[id as usize];
            for row in [Row::F, Row::U, Row::B] {
                m.push_view(row, r.row(row).view());
            }
        }
        Ok(m)
    }
}

/// `G_max` given to a light inside a record's ball of radius `r` (module docs).
pub fn inside_bound(r: f32) -> f64 {
    let q = r as f64 / 4.0;
    1.0 / (q * q)
}

/// Row B's value of light `v` at a record of region `region` whose diffuse `f_s` is
/// `f_s` (module docs), and `u`, its row-U value (B is never below it).
pub fn b_value(v: &Vpl, region: &super::bound::Region, f_s: Vec3, disk_area: f32, u: f64) -> f64 {
    let b = if v.kind == VplKind::Env {
        luminance(f_s * v.flux) as f64 / disk_area as f64
            * super::bound::directional_bound(region, v.normal)
    } else {
        let intensity = v
            .diffuse_intensity()
            .unwrap_or(v.flux * std::f32::consts::FRAC_1_PI);
        let g = super::bound::point_bound(region, v.origin, v.normal);
        let g = if g.is_finite() {
            g
        } else {
            inside_bound(region.radius)
        };
        luminance(f_s * intensity) as f64 * g
    };
    if b.is_finite() {
        b.max(u)
    } else {
        u
    }
}

#[cfg(test)]
mod tests;
