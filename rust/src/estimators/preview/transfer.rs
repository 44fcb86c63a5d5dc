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

use super::haar;
use super::light::cell_integrals;
use crate::bsdf::Material;
use crate::error::{Error, Result};
use crate::estimators::direct::ProductLevel;
use crate::lights::envmap::EnvMap;
use crate::visibility::cache::{CacheState, VisibilityCache};
use crate::visibility::params::CacheParams;

/// Finest transfer level: Haar indices are `u16` (`4^8` coefficients).
pub const MAX_TRANSFER_LEVEL: u32 = 8;

/// Pixels per parallel work item.
const CHUNK: usize = 256;

/// How a pixel's transfer is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Basis {
    /// Cell averages of `T` at `level` (dense, `4^level` values a pixel).
    Texels { level: u32 },
    /// The `terms` largest Haar coefficients of `T` at the full level (index and value).
    Haar { terms: u32 },
}

impl Basis {
    /// Bytes a pixel's transfer takes.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            Basis::Texels { level } => 4 << (2 * level),
            Basis::Haar { terms } => 6 * terms as usize,
        }
    }

    /// Short name (`"texels"`, `"haar"`).
    pub fn name(self) -> &'static str {
        match self {
            Basis::Texels { .. } => "texels",
            Basis::Haar { .. } => "haar",
        }
    }
}

/// What a transfer is built from besides the view: the cache's records and these.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TransferSettings {
    /// Level of the product's `B~` cells.
    pub product_level: ProductLevel,
    /// `Ṽ` from the heaviest record alone instead of the cache's `β`-weighted blend
    /// (CAM08's nearest-record preview, for comparison).
    pub nearest: bool,
}

impl TransferSettings {
    /// The renderer's product levels and the cache's interpolation.
    pub const DEFAULT: Self = Self {
        product_level: ProductLevel::PerMaterial,
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
        out.fill(0.0);
        let lookup =
            self.state
                .lookup_records(self.params, point.position, point.normal, point.radius);
        let mut neighbours = lookup.neighbours();
        if neighbours.is_empty() {
            return false;
        }
        if self.settings.nearest {
            neighbours = &neighbours[..1];
        }
        let p = self
            .settings
            .product_level
            .for_material(&point.material)
            .min(self.level);
        self.cells.resize(1 << (2 * p), 0.0);
        point
            .material
            .product_cells(point.normal, point.wo, p, &mut self.cells);
        if self.cells.iter().all(|&b| b <= 0.0) {
            return false;
        }
        // Ṽ at the full level: each record texel covers 4^(L - m) cells.
        let store = self.state.store();
        let m = store.m();
        let spread = 2 * (self.level - m);
        for k in neighbours {
            let beta = if self.settings.nearest {
                1.0
            } else {
                k.beta as f64
            };
            for (w, &word) in store.bits(k.id as usize).bit_words().iter().enumerate() {
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
    /// Per row, `stride` coefficient indices (Haar only).
    index: Vec<u16>,
    /// Per row, `stride` values.
    values: Vec<f32>,
    stride: usize,
}

/// [`Transfer::row_of`] of a pixel without a transfer.
pub const NO_ROW: u32 = u32::MAX;

/// A light vector in a transfer's basis: per coefficient, RGB.
#[derive(Clone, Debug)]
pub struct LightCoefficients {
    basis: Basis,
    values: Vec<[f64; 3]>,
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
            .map(|mat| settings.product_level.for_material(mat))
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
    /// full level `level`, from `cache` under `settings`.
    pub fn build(
        points: &[Option<TransferPoint>],
        cache: &VisibilityCache,
        settings: TransferSettings,
        level: u32,
        basis: Basis,
    ) -> Result<Self> {
        let stride = match basis {
            Basis::Texels { level: l } if l > level => {
                return Err(Error::invalid(
                    "basis",
                    format!("texels of level {l} are finer than the transfer's {level}"),
                ))
            }
            Basis::Texels { level: l } => 1usize << (2 * l),
            Basis::Haar { terms } => (terms as usize).clamp(1, 1 << (2 * level)),
        };
        let state = cache.read();
        let params = cache.params();
        let chunks: Vec<(Vec<bool>, Vec<u16>, Vec<f32>)> = points
            .par_chunks(CHUNK)
            .map(|chunk| {
                let mut builder = PixelTransfer::new(&state, params, settings, level);
                let mut enc = Encoder::new(level, basis, stride);
                let mut present = Vec::with_capacity(chunk.len());
                let (mut index, mut values) = (Vec::new(), Vec::new());
                for point in chunk {
                    let ok = match point {
                        Some(p) => builder.dense(p, &mut enc.dense),
                        None => false,
                    };
                    present.push(ok);
                    if ok {
                        enc.encode(&mut index, &mut values);
                    }
                }
                (present, index, values)
            })
            .collect();
        let mut t = Self {
            basis,
            level,
            row_of: Vec::with_capacity(points.len()),
            index: Vec::new(),
            values: Vec::new(),
            stride,
        };
        let mut rows = 0u32;
        for (present, index, values) in chunks {
            for ok in present {
                t.row_of.push(if ok { rows } else { NO_ROW });
                rows += ok as u32;
            }
            t.index.extend_from_slice(&index);
            t.values.extend_from_slice(&values);
        }
        Ok(t)
    }

    /// Rebuilds the rows of `pixels` (indices into `points`) after an edit of their
    /// materials; other rows stay as they are. Returns how many pixels changed.
    pub fn rebuild(
        &mut self,
        points: &[Option<TransferPoint>],
        pixels: &[usize],
        cache: &VisibilityCache,
        settings: TransferSettings,
    ) -> usize {
        let state = cache.read();
        let params = cache.params();
        let (level, basis, stride) = (self.level, self.basis, self.stride);
        let rows: Vec<(usize, bool, Vec<u16>, Vec<f32>)> = pixels
            .par_chunks(CHUNK)
            .flat_map_iter(|chunk| {
                let mut builder = PixelTransfer::new(&state, params, settings, level);
                let mut enc = Encoder::new(level, basis, stride);
                chunk
                    .iter()
                    .map(|&i| {
                        let ok = points[i].is_some_and(|p| builder.dense(&p, &mut enc.dense));
                        let (mut index, mut values) = (Vec::new(), Vec::new());
                        if ok {
                            enc.encode(&mut index, &mut values);
                        }
                        (i, ok, index, values)
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        for (i, ok, index, values) in rows {
            if !ok {
                self.row_of[i] = NO_ROW;
                continue;
            }
            if self.row_of[i] == NO_ROW {
                self.row_of[i] = (self.values.len() / stride) as u32;
                self.values.resize(self.values.len() + stride, 0.0);
                if matches!(basis, Basis::Haar { .. }) {
                    self.index.resize(self.index.len() + stride, 0);
                }
            }
            let r = self.row_of[i] as usize * stride;
            self.values[r..r + stride].copy_from_slice(&values);
            if !index.is_empty() {
                self.index[r..r + stride].copy_from_slice(&index);
            }
        }
        pixels.len()
    }

    /// Pixels with a transfer (rows).
    pub fn rows(&self) -> usize {
        self.values.len() / self.stride
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
        4 * self.row_of.len() + 2 * self.index.len() + 4 * self.values.len()
    }

    /// `env` (turned by `rotation`) in this transfer's basis.
    pub fn light(&self, env: &EnvMap, rotation: Option<&DMat3>) -> Result<LightCoefficients> {
        let values = match self.basis {
            Basis::Texels { level } => cell_integrals(env, level, rotation)?,
            Basis::Haar { .. } => {
                let cells = cell_integrals(env, self.level, rotation)?;
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
        };
        Ok(LightCoefficients {
            basis: self.basis,
            values,
        })
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
        let values = &self.values[r..r + self.stride];
        let l = &light.values;
        let mut acc = [0.0f64; 3];
        let mut add = |v: f32, c: &[f64; 3]| {
            let v = v as f64;
            acc = [acc[0] + v * c[0], acc[1] + v * c[1], acc[2] + v * c[2]];
        };
        match self.basis {
            Basis::Texels { .. } => {
                for (v, c) in values.iter().zip(l) {
                    add(*v, c);
                }
            }
            Basis::Haar { .. } => {
                for (&v, &j) in values.iter().zip(&self.index[r..r + self.stride]) {
                    add(v, &l[j as usize]);
                }
            }
        }
        acc
    }
}

/// Turns a dense `T` into one row of a basis.
struct Encoder {
    level: u32,
    basis: Basis,
    stride: usize,
    /// The dense `T` (filled by the caller).
    dense: Vec<f64>,
    scratch: Vec<f64>,
    order: Vec<u16>,
}

impl Encoder {
    fn new(level: u32, basis: Basis, stride: usize) -> Self {
        let n = 1usize << (2 * level);
        Self {
            level,
            basis,
            stride,
            dense: vec![0.0; n],
            scratch: vec![0.0; n],
            order: (0..n).map(|i| i as u16).collect(),
        }
    }

    /// Appends the row of `self.dense` (`stride` values, and indices for Haar).
    fn encode(&mut self, index: &mut Vec<u16>, values: &mut Vec<f32>) {
        match self.basis {
            Basis::Texels { level } => {
                // Cell averages at the coarser level.
                let per = 1usize << (2 * (self.level - level));
                let scale = 1.0 / per as f64;
                values.extend(
                    self.dense
                        .chunks_exact(per)
                        .map(|c| (c.iter().sum::<f64>() * scale) as f32),
                );
            }
            Basis::Haar { .. } => {
                haar::forward(&mut self.dense, &mut self.scratch);
                let k = self.stride;
                let dense = &self.dense;
                let n = dense.len();
                for (i, o) in self.order.iter_mut().enumerate() {
                    *o = i as u16;
                }
                if k < n {
                    // The k largest magnitudes (ties by index: the same row on every run).
                    self.order.select_nth_unstable_by(k - 1, |&a, &b| {
                        let (x, y) = (dense[a as usize].abs(), dense[b as usize].abs());
                        y.total_cmp(&x).then(a.cmp(&b))
                    });
                }
                let kept = &mut self.order[..k];
                kept.sort_unstable();
                for &i in kept.iter() {
                    index.push(i);
                    values.push(dense[i as usize] as f32);
                }
            }
        }
    }
}
