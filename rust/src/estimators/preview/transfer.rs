//! Cached transfer (CAM08 §6.2's cure for the preview's cost, after Ng et al. 2003): per
//! pixel, the lighting-independent factor of the preview's integral
//! `J_c = ∫ L_c(ω) T(ω) dω`, `T = B~ Ṽ` (the product's reflectance cells times the cache's
//! interpolated visibility), computed once per view and cache and kept in a basis where a
//! lighting change is one projection of the map and a dot product per pixel.
//!
//! ## Exactness at full resolution
//! `B~` is constant over the product's cells (level `p`) and every record's `V_i` over its
//! texels (level `m`), so `T` is constant over the cells of level `L = max(m, p)`, and
//! `J_c = Σ_cell T(cell) ∫_cell L_c dω` exactly — with the map's own colour in every
//! texel. Kept whole ([`Basis::Texels`] at level `L`, or Haar with every coefficient) the
//! transfer gives that `J`; the bases below trade it for memory and time:
//! - [`Basis::Texels`] at a coarser level: `T` averaged over bigger cells (blurs shadows).
//! - [`Basis::Haar`]: the `terms` largest orthonormal Haar coefficients of `T` at level
//!   `L` per pixel (non-linear approximation: sharp features where the pixel has them).
//! - [`Basis::Sh`]: spherical harmonics of `T` to `order` (smooth lighting only; rings
//!   under a sun).

use glam::{DMat3, Vec3};
use rayon::prelude::*;

use std::sync::Arc;

use super::bright::BrightCells;
use super::light::cell_integrals;
use super::{dot, haar};
use crate::bsdf::Material;
use crate::error::{Error, Result};
use crate::estimators::direct::ProductLevel;
use crate::lights::envmap::EnvMap;
use crate::sampling::sh::{self, CellBasis};
use crate::stop::Stop;
use crate::visibility::cache::{CacheState, VisibilityCache};
use crate::visibility::params::CacheParams;
use crate::visibility::record::VisibilityView;

/// Finest transfer level: Haar indices are `u16` (`4^8` coefficients).
pub const MAX_TRANSFER_LEVEL: u32 = 8;

/// Pixels per parallel work item.
const CHUNK: usize = 256;

/// How a pixel's transfer is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Basis {
    /// Cell averages of `T` at `level` (dense, `4^level` `f32` values a pixel).
    Texels { level: u32 },
    /// The `terms` largest Haar coefficients of `T` at the full level: per pixel one `f32`
    /// scale, then per term its index (`u16`) and its value over the scale in 15 bits
    /// (`i16`, rounding error at most `2^-16` of the pixel's largest term).
    Haar { terms: u32 },
    /// Spherical harmonics of `T` to `order` (`order²` `f32` values a pixel), projected
    /// from `T`'s averages over the cells of level [`SH_CELL_LEVEL`]; the map's
    /// coefficients come from its texels and turn by SH rotation matrices.
    Sh { order: u32 },
}

/// Level of the cells a pixel's `T` is averaged over before its SH projection.
pub const SH_CELL_LEVEL: u32 = 5;

/// Highest SH order a transfer takes (64 coefficients).
pub const MAX_SH_ORDER: u32 = 8;

impl Basis {
    /// Bytes a pixel's transfer takes.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            Basis::Texels { level } => 4 << (2 * level),
            Basis::Haar { terms } => 4 + 4 * terms as usize,
            Basis::Sh { order } => 4 * sh::coefficient_count(order),
        }
    }

    /// Short name (`"texels"`, `"haar"`).
    pub fn name(self) -> &'static str {
        match self {
            Basis::Texels { .. } => "texels",
            Basis::Haar { .. } => "haar",
            Basis::Sh { .. } => "sh",
        }
    }
}

/// What a transfer is built from besides the view: the cache's records and these.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TransferSettings {
    /// Level of the product's `B~` cells; `None`: the transfer's full level (the finest
    /// the transfer holds anyway, so free after preparation; it follows `B cos θ` closer
    /// than the renderer's coarser sampling cells).
    pub product_level: Option<ProductLevel>,
    /// `Ṽ` from the heaviest record alone instead of the cache's `β`-weighted blend
    /// (CAM08's nearest-record preview, for comparison).
    pub nearest: bool,
}

impl TransferSettings {
    /// `B~` at the full level and the cache's interpolation.
    pub const DEFAULT: Self = Self {
        product_level: None,
        nearest: false,
    };
}

/// What [`PixelTransfer::dense`] reads of one pixel.
#[derive(Clone, Copy, Debug)]
pub struct TransferPoint {
    pub position: Vec3,
    /// Unit normal facing the camera.
    pub normal: Vec3,
    /// Unit direction to the eye.
    pub wo: Vec3,
    /// Lookup radius (world units).
    pub radius: f32,
    pub material: Material,
}

impl TransferPoint {
    /// What the bright cells' light here depends on.
    pub fn shading(&self) -> super::bright::Shading {
        super::bright::Shading {
            normal: self.normal,
            wo: self.wo,
            material: self.material,
        }
    }
}

/// Builds the dense transfer `T` of points at one level (module docs). One per thread.
pub struct PixelTransfer<'a> {
    state: &'a CacheState,
    params: &'a CacheParams,
    settings: TransferSettings,
    /// The full level `L = max(m, p_max)`.
    level: u32,
    cells: Vec<f32>,
}

impl<'a> PixelTransfer<'a> {
    /// A builder at `level` (at least the records' level and every product level used).
    pub fn new(
        state: &'a CacheState,
        params: &'a CacheParams,
        settings: TransferSettings,
        level: u32,
    ) -> Self {
        Self {
            state,
            params,
            settings,
            level,
            cells: Vec::new(),
        }
    }

    /// `T` of `point` per cell of the full level (Morton order) into `out`; false when it
    /// is zero everywhere (no records, or a surface reflecting nothing towards the eye).
    pub fn dense(&mut self, point: &TransferPoint, out: &mut [f64]) -> bool {
        let lookup =
            self.state
                .lookup_records(self.params, point.position, point.normal, point.radius);
        let mut neighbours = lookup.neighbours();
        if neighbours.is_empty() {
            out.fill(0.0);
            return false;
        }
        if self.settings.nearest {
            neighbours = &neighbours[..1];
        }
        let store = self.state.store();
        let maps: Vec<(VisibilityView, f64)> = neighbours
            .iter()
            .map(|k| {
                let beta = if self.settings.nearest {
                    1.0
                } else {
                    k.beta as f64
                };
                (store.bits(k.id as usize), beta)
            })
            .collect();
        self.dense_with(point, &maps, out)
    }

    /// `T` of `point` with `V = Σ β V_i` over `maps` (records' visibility and their
    /// weights; one exact record of the point itself gives the exact `T`).
    pub fn dense_with(
        &mut self,
        point: &TransferPoint,
        maps: &[(VisibilityView, f64)],
        out: &mut [f64],
    ) -> bool {
        out.fill(0.0);
        let p = match self.settings.product_level {
            Some(level) => level.for_material(&point.material).min(self.level),
            None => self.level,
        };
        self.cells.resize(1 << (2 * p), 0.0);
        point
            .material
            .product_cells(point.normal, point.wo, p, &mut self.cells);
        if self.cells.iter().all(|&b| b <= 0.0) {
            return false;
        }
        // Ṽ at the full level: each record texel covers 4^(L - m) cells, or each cell
        // 4^(m - L) texels of a finer record (its visible share).
        for (bits, beta) in maps {
            if bits.m() > self.level {
                let per = 1usize << (2 * (bits.m() - self.level));
                let share = beta / per as f64;
                for (cell, v) in out.iter_mut().enumerate() {
                    let visible = (cell * per..(cell + 1) * per)
                        .filter(|&z| bits.get(z))
                        .count();
                    *v += share * visible as f64;
                }
                continue;
            }
            let spread = 2 * (self.level - bits.m());
            for (w, &word) in bits.bit_words().iter().enumerate() {
                let mut x = word;
                while x != 0 {
                    let texel = 64 * w + x.trailing_zeros() as usize;
                    x &= x - 1;
                    for v in &mut out[texel << spread..(texel + 1) << spread] {
                        *v += beta;
                    }
                }
            }
        }
        // Times B~ of each cell's product cell.
        let shift = 2 * (self.level - p);
        let mut any = false;
        for (i, v) in out.iter_mut().enumerate() {
            *v *= self.cells[i >> shift] as f64;
            any |= *v != 0.0;
        }
        any
    }
}

/// The transfer of every pixel of a view in one [`Basis`], and the light vectors it needs.
#[derive(Clone, Debug)]
pub struct Transfer {
    basis: Basis,
    /// The full level `L` (module docs).
    level: u32,
    /// Per pixel: its row, or [`NO_ROW`] where `T = 0` (escaped, unlit, no records).
    row_of: Vec<u32>,
    /// Per row, `stride` words: `f32` cell values, or for Haar the row's `f32` scale and
    /// then per term `index << 16 | value as u16` ([`Basis::Haar`]).
    words: Vec<u32>,
    /// Words per row.
    stride: usize,
    /// Haar truncation weights by level ([`Transfer::build`]).
    level_weights: Vec<f64>,
    /// The SH basis over cells ([`Basis::Sh`]).
    sh_basis: Option<Arc<CellBasis>>,
}

/// [`Transfer::row_of`] of a pixel without a transfer.
pub const NO_ROW: u32 = u32::MAX;

/// A light vector in a transfer's basis: per coefficient, RGB.
#[derive(Clone, Debug)]
pub struct LightCoefficients {
    basis: Basis,
    values: Vec<[f64; 3]>,
    /// `values` as `f32` RGB plus a zero lane, for the Haar rows' inner loop
    /// ([`dot::haar_sums`]).
    packed: Vec<[f32; 4]>,
    /// `values` by channel, for the dense rows' inner loop ([`dot::dense_sums`]).
    dense: [Vec<f64>; 3],
}

impl LightCoefficients {
    /// Per coefficient, RGB (`∫ L_c` against the basis function).
    pub fn values(&self) -> &[[f64; 3]] {
        &self.values
    }
}

impl Transfer {
    /// The level a transfer of `cache` takes for `materials` under `settings`: the records'
    /// level or the finest product level, whichever is finer. Fails above
    /// [`MAX_TRANSFER_LEVEL`].
    pub fn full_level<'m>(
        cache: &VisibilityCache,
        materials: impl Iterator<Item = &'m Material>,
        settings: &TransferSettings,
    ) -> Result<u32> {
        let m = cache.params().log2_resolution;
        let p = materials
            .map(|mat| {
                settings
                    .product_level
                    .unwrap_or(ProductLevel::PerMaterial)
                    .for_material(mat)
            })
            .max()
            .unwrap_or(1);
        let level = m.max(p);
        if level > MAX_TRANSFER_LEVEL {
            return Err(Error::invalid(
                "cache",
                format!(
                    "a transfer needs records and product cells of level <= \
                     {MAX_TRANSFER_LEVEL} (got {level})"
                ),
            ));
        }
        Ok(level)
    }

    /// Builds the transfer of `points` (`None` for pixels without one) in `basis` at the
    /// full level `level`, from `cache` under `settings`. A Haar basis keeps per pixel the
    /// coefficients of largest `|c| w(l)`, `w` = `level_weights` by level ([`level_weights`];
    /// `None`: all 1, the best approximation of `T` alone).
    pub fn build(
        points: &[Option<TransferPoint>],
        cache: &VisibilityCache,
        settings: TransferSettings,
        level: u32,
        basis: Basis,
        level_weights: Option<Vec<f64>>,
    ) -> Result<Self> {
        let level_weights = level_weights.unwrap_or_else(|| vec![1.0; level as usize + 1]);
        if level_weights.len() != level as usize + 1 {
            return Err(Error::invalid(
                "level_weights",
                format!("needs {} weights, got {}", level + 1, level_weights.len()),
            ));
        }
        let stride = match basis {
            Basis::Texels { level: l } if l > level => {
                return Err(Error::invalid(
                    "basis",
                    format!("texels of level {l} are finer than the transfer's {level}"),
                ))
            }
            Basis::Texels { level: l } => 1usize << (2 * l),
            Basis::Haar { terms } => 1 + (terms as usize).clamp(1, 1 << (2 * level)),
            Basis::Sh { order } if !(1..=MAX_SH_ORDER).contains(&order) => {
                return Err(Error::invalid(
                    "basis",
                    format!("an SH order must lie in [1, {MAX_SH_ORDER}], got {order}"),
                ))
            }
            Basis::Sh { order } => sh::coefficient_count(order),
        };
        let sh_basis = match basis {
            Basis::Sh { order } => Some(Arc::new(CellBasis::new(order, SH_CELL_LEVEL.min(level)))),
            _ => None,
        };
        let state = cache.read();
        let params = cache.params();
        let stop = Stop::current();
        let chunks: Vec<(Vec<bool>, Vec<u32>)> = points
            .par_chunks(CHUNK)
            .map(|chunk| {
                let mut builder = PixelTransfer::new(&state, params, settings, level);
                let mut enc = Encoder::new(level, basis, stride, &level_weights, &sh_basis);
                let mut present = Vec::with_capacity(chunk.len());
                let mut words = Vec::new();
                for point in chunk {
                    // A pixel of a fine level is milliseconds: polled per pixel.
                    if stop.is_set() {
                        break;
                    }
                    let ok = match point {
                        Some(p) => builder.dense(p, &mut enc.dense),
                        None => false,
                    };
                    present.push(ok);
                    if ok {
                        enc.encode(&mut words);
                    }
                }
                (present, words)
            })
            .collect();
        stop.check("building the transfer")?;
        let mut t = Self {
            basis,
            level,
            row_of: Vec::with_capacity(points.len()),
            words: Vec::new(),
            stride,
            level_weights,
            sh_basis,
        };
        let mut rows = 0u32;
        for (present, words) in chunks {
            for ok in present {
                t.row_of.push(if ok { rows } else { NO_ROW });
                rows += ok as u32;
            }
            t.words.extend_from_slice(&words);
        }
        Ok(t)
    }

    /// Rebuilds the rows of `pixels` (indices into `points`) after an edit of their
    /// materials; other rows stay as they are. Returns how many pixels changed. Stops
    /// with [`Error::Interrupted`] when the current [`Stop`] is set, some rows rebuilt and
    /// others not: the caller drops the transfer then.
    pub fn rebuild(
        &mut self,
        points: &[Option<TransferPoint>],
        pixels: &[usize],
        cache: &VisibilityCache,
        settings: TransferSettings,
    ) -> Result<usize> {
        let stop = Stop::current();
        let state = cache.read();
        let params = cache.params();
        let (level, basis, stride) = (self.level, self.basis, self.stride);
        let weights = &self.level_weights;
        let sh_basis = &self.sh_basis;
        let rows: Vec<(usize, bool, Vec<u32>)> = pixels
            .par_chunks(CHUNK)
            .flat_map_iter(|chunk| {
                let mut builder = PixelTransfer::new(&state, params, settings, level);
                let mut enc = Encoder::new(level, basis, stride, weights, sh_basis);
                chunk
                    .iter()
                    .take_while(|_| !stop.is_set())
                    .map(|&i| {
                        let ok = points[i].is_some_and(|p| builder.dense(&p, &mut enc.dense));
                        let mut words = Vec::new();
                        if ok {
                            enc.encode(&mut words);
                        }
                        (i, ok, words)
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        for (i, ok, words) in rows {
            if !ok {
                self.row_of[i] = NO_ROW;
                continue;
            }
            if self.row_of[i] == NO_ROW {
                self.row_of[i] = (self.words.len() / stride) as u32;
                self.words.resize(self.words.len() + stride, 0);
            }
            let r = self.row_of[i] as usize * stride;
            self.words[r..r + stride].copy_from_slice(&words);
        }
        stop.check("rebuilding the transfer")?;
        Ok(pixels.len())
    }

    /// Pixels with a transfer (rows).
    pub fn rows(&self) -> usize {
        self.words.len() / self.stride
    }

    /// A Haar row's scale (its largest term's magnitude; a value's rounding error is at
    /// most `scale / 2 / i16::MAX`); `None` for other bases and pixels without a row.
    pub fn haar_scale(&self, i: usize) -> Option<f32> {
        let row = self.row_of[i];
        (matches!(self.basis, Basis::Haar { .. }) && row != NO_ROW)
            .then(|| f32::from_bits(self.words[row as usize * self.stride]))
    }

    /// The basis.
    pub fn basis(&self) -> Basis {
        self.basis
    }

    /// The full level `L`.
    pub fn level(&self) -> u32 {
        self.level
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> usize {
        4 * self.row_of.len() + 4 * self.words.len()
    }

    /// `env` (turned by `rotation`) in this transfer's basis.
    pub fn light(&self, env: &EnvMap, rotation: Option<&DMat3>) -> Result<LightCoefficients> {
        let cells = cell_integrals(env, self.level, rotation)?;
        self.light_for(env, rotation, cells, &BrightCells::default())
    }

    /// `env` turned by `rotation` in this transfer's basis, without the light of `bright`
    /// (which pixels add exactly); `cells` are the turned map's integrals over the cells of
    /// the full level, the bright ones already zeroed ([`BrightCells::split`]). Texel and
    /// Haar bases read `cells`; SH projects the map's texels, turns the coefficients by
    /// SH rotation matrices and takes out each bright cell's light as a point light at
    /// its direction.
    pub fn light_for(
        &self,
        env: &EnvMap,
        rotation: Option<&DMat3>,
        cells: Vec<[f64; 3]>,
        bright: &BrightCells,
    ) -> Result<LightCoefficients> {
        debug_assert_eq!(cells.len(), 1 << (2 * self.level));
        let values = match self.basis {
            Basis::Texels { level } => {
                let per = 1usize << (2 * (self.level - level));
                cells
                    .chunks_exact(per)
                    .map(|c| {
                        c.iter()
                            .fold([0.0; 3], |a, x| [a[0] + x[0], a[1] + x[1], a[2] + x[2]])
                    })
                    .collect()
            }
            Basis::Haar { .. } => {
                let n = cells.len();
                let mut out = vec![[0.0; 3]; n];
                let (mut channel, mut scratch) = (vec![0.0; n], vec![0.0; n]);
                for k in 0..3 {
                    for (c, v) in channel.iter_mut().zip(&cells) {
                        *c = v[k];
                    }
                    haar::forward(&mut channel, &mut scratch);
                    for (o, c) in out.iter_mut().zip(&channel) {
                        o[k] = *c;
                    }
                }
                out
            }
            Basis::Sh { order } => {
                let mut coeffs = sh::project_texels(order, env.texels(), env.resolution());
                if let Some(r) = rotation {
                    let turned = sh::Rotation::new(order, *r)?;
                    let mut out = vec![[0.0; 3]; coeffs.len()];
                    turned.apply_rgb(&coeffs, &mut out);
                    coeffs = out;
                }
                let mut y = vec![0.0; coeffs.len()];
                for (dir, rgb) in bright.dirs.iter().zip(&bright.rgb) {
                    sh::eval(order, dir.as_dvec3(), &mut y);
                    for (c, yk) in coeffs.iter_mut().zip(&y) {
                        for k in 0..3 {
                            c[k] -= rgb[k] * yk;
                        }
                    }
                }
                coeffs
            }
        };
        let (packed, dense) = match self.basis {
            Basis::Haar { .. } => (
                values
                    .iter()
                    .map(|v| [v[0] as f32, v[1] as f32, v[2] as f32, 0.0])
                    .collect(),
                Default::default(),
            ),
            _ => (
                Vec::new(),
                std::array::from_fn(|c| values.iter().map(|v| v[c]).collect()),
            ),
        };
        Ok(LightCoefficients {
            basis: self.basis,
            values,
            packed,
            dense,
        })
    }

    /// True when pixel `i` has a transfer (a non-zero `T`).
    pub fn has_row(&self, i: usize) -> bool {
        self.row_of[i] != NO_ROW
    }

    /// True when the basis keeps `T` whole (cell values at the full level).
    pub fn is_whole(&self) -> bool {
        self.basis == Basis::Texels { level: self.level }
    }

    /// `Σ T l_c` of pixel `i` under `light` (zero without a transfer).
    #[inline]
    pub fn eval(&self, i: usize, light: &LightCoefficients) -> [f64; 3] {
        debug_assert_eq!(light.basis, self.basis);
        let row = self.row_of[i];
        if row == NO_ROW {
            return [0.0; 3];
        }
        let r = row as usize * self.stride;
        let words = &self.words[r..r + self.stride];
        match self.basis {
            Basis::Texels { .. } | Basis::Sh { .. } => {
                let [r, g, b] = &light.dense;
                dot::dense_sums(words, [r, g, b])
            }
            Basis::Haar { .. } => {
                // f32 lanes: the sum's rounding stays far below the values' 15 bits.
                let sums = dot::haar_sums(&words[1..], &light.packed);
                let scale = f32::from_bits(words[0]) as f64 / QUANTUM;
                std::array::from_fn(|c| {
                    let total = (sums[0][c] + sums[1][c]) + (sums[2][c] + sums[3][c]);
                    total as f64 * scale
                })
            }
        }
    }
}

/// Largest magnitude of a quantised Haar value: a row's largest term.
const QUANTUM: f64 = i16::MAX as f64;

/// Turns a dense `T` into one row of a basis.
struct Encoder {
    level: u32,
    basis: Basis,
    stride: usize,
    /// The dense `T` (filled by the caller).
    dense: Vec<f64>,
    scratch: Vec<f64>,
    /// The non-zero Haar terms of a row: weighted magnitude and index.
    order: Vec<(f64, u16)>,
    /// Per Haar coefficient, the weight of its level.
    weights: Vec<f64>,
    sh_basis: Option<Arc<CellBasis>>,
    /// `T` averaged over the SH basis's cells.
    sh_cells: Vec<f32>,
    sh_out: Vec<f32>,
}

/// The level-weight slot of Haar coefficient `k` (0 the root's scaling, `1 + l` the details
/// of level `l`).
fn weight_slot(k: usize) -> usize {
    if k == 0 {
        0
    } else {
        1 + (k.ilog2() / 2) as usize
    }
}

impl Encoder {
    fn new(
        level: u32,
        basis: Basis,
        stride: usize,
        level_weights: &[f64],
        sh_basis: &Option<Arc<CellBasis>>,
    ) -> Self {
        let n = 1usize << (2 * level);
        let sh_cells = sh_basis.as_ref().map_or(0, |b| b.cells());
        Self {
            sh_basis: sh_basis.clone(),
            sh_cells: vec![0.0; sh_cells],
            sh_out: vec![0.0; stride],
            level,
            basis,
            stride,
            dense: vec![0.0; n],
            scratch: vec![0.0; n],
            order: Vec::with_capacity(n),
            weights: (0..n).map(|k| level_weights[weight_slot(k)]).collect(),
        }
    }

    /// Appends the row of `self.dense` (`stride` words, [`Transfer::words`]).
    fn encode(&mut self, words: &mut Vec<u32>) {
        match self.basis {
            Basis::Texels { level } => {
                // Cell averages at the coarser level.
                let per = 1usize << (2 * (self.level - level));
                let scale = 1.0 / per as f64;
                words.extend(
                    self.dense
                        .chunks_exact(per)
                        .map(|c| ((c.iter().sum::<f64>() * scale) as f32).to_bits()),
                );
            }
            Basis::Sh { .. } => {
                let basis = self
                    .sh_basis
                    .as_ref()
                    .expect("an SH transfer has its basis");
                let per = self.dense.len() / basis.cells();
                let scale = 1.0 / per as f64;
                for (o, c) in self.sh_cells.iter_mut().zip(self.dense.chunks_exact(per)) {
                    *o = (c.iter().sum::<f64>() * scale) as f32;
                }
                basis.project(&self.sh_cells, &mut self.sh_out);
                words.extend(self.sh_out.iter().map(|v| v.to_bits()));
            }
            Basis::Haar { .. } => {
                haar::forward(&mut self.dense, &mut self.scratch);
                let k = self.stride - 1;
                // The non-zero terms with their weighted magnitudes (most are zero: T
                // vanishes below the surface and where every record is blocked).
                let kept = &mut self.order;
                kept.clear();
                kept.extend(
                    self.dense
                        .iter()
                        .zip(&self.weights)
                        .enumerate()
                        .filter(|(_, (c, _))| **c != 0.0)
                        .map(|(i, (c, w))| (c.abs() * w, i as u16)),
                );
                if kept.len() > k {
                    // The k largest (ties by index: the same row on every run).
                    kept.select_nth_unstable_by(k - 1, |a, b| {
                        b.0.total_cmp(&a.0).then(a.1.cmp(&b.1))
                    });
                    kept.truncate(k);
                }
                kept.sort_unstable_by_key(|t| t.1);
                let dense = &self.dense;
                let largest = kept
                    .iter()
                    .map(|t| dense[t.1 as usize].abs())
                    .fold(0.0, f64::max);
                let scale = largest as f32;
                words.push(scale.to_bits());
                let to_unit = if scale > 0.0 {
                    QUANTUM / scale as f64
                } else {
                    0.0
                };
                for &(_, i) in kept.iter() {
                    let q = (dense[i as usize] * to_unit).round() as i16;
                    words.push(((i as u32) << 16) | q as u16 as u32);
                }
                // Rows are `stride` words: pad with zero terms.
                words.resize(words.len() + k - kept.len(), 0);
            }
        }
    }
}

/// Haar truncation weights for lighting like the light whose integrals over the cells of
/// the full level are `cells` (Morton): per level, the root-mean-square of its luminance
/// detail coefficients there (the root's scaling coefficient for slot 0), so that a pixel
/// keeps the terms `|T_k| w` that matter most under lighting of that spectrum. By level
/// only, so they hold for the map turned any way. All 1 for a black light.
pub fn level_weights(cells: &[[f64; 3]]) -> Vec<f64> {
    let level = haar::level_of(cells.len()).expect("4^L cells");
    let mut lum: Vec<f64> = cells
        .iter()
        .map(|c| {
            c.iter()
                .zip(crate::lights::envmap::LUMINANCE)
                .map(|(x, w)| x * w)
                .sum()
        })
        .collect();
    let mut scratch = vec![0.0; lum.len()];
    haar::forward(&mut lum, &mut scratch);
    let mut sums = vec![(0.0f64, 0usize); level as usize + 1];
    for (k, c) in lum.iter().enumerate() {
        let s = &mut sums[weight_slot(k)];
        s.0 += c * c;
        s.1 += 1;
    }
    let w: Vec<f64> = sums.iter().map(|&(s, n)| (s / n as f64).sqrt()).collect();
    let max = w.iter().cloned().fold(0.0, f64::max);
    if max > 0.0 && max.is_finite() {
        w.iter().map(|x| x / max).collect()
    } else {
        vec![1.0; level as usize + 1]
    }
}
