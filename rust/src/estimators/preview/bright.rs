//! The few brightest cells of a map, taken out of a truncated transfer and integrated
//! exactly per pixel (the split Ng et al. 2003 make implicitly by truncating the lighting).
//!
//! A sun holds most of a map's power in one or two cells. A pixel's truncated transfer
//! keeps its largest terms, which describe `T` well on average but not in the cell the sun
//! happens to light it from; there, a dropped term times the sun's radiance is the whole
//! error (dynamics at 160 Haar terms: relMSE 0.10 against 0.066 whole). So every lighting
//! change moves the cells that hold a concentrated light — at most [`MAX_BRIGHT`], each at
//! least [`BRIGHT_FACTOR`] times the mean — out of the projection, and each pixel adds
//! `Σ_s l_c(s) B(ω_s) cos θ_s Ṽ(ω_s)` for them: the BSDF at the light's centroid direction
//! `ω_s` in the cell and the cache's `Ṽ = Σ β_i V_i` from the pixel's kept records.

use glam::{DMat3, DVec3, UVec2, Vec3};
use rayon::prelude::*;

use super::transfer::TransferPoint;
use crate::bsdf::Material;
use crate::error::Result;
use crate::lights::envmap::{EnvMap, LUMINANCE};
use crate::sampling::octahedral::{
    morton_decode, morton_encode, square_to_sphere, texel_center, texel_of,
};
use crate::stop::Stop;
use crate::visibility::cache::CacheState;
use crate::visibility::params::CacheParams;

/// Most cells taken out of the projection.
pub const MAX_BRIGHT: usize = 8;

/// Shadow rays a pixel traces toward a bright cell ([`BrightCells::aim`]).
pub const AIMS: usize = 4;

/// A cell is bright when its luminance is at least this many times the mean cell's (it
/// holds at least `BRIGHT_FACTOR / 4^L` of the map's power).
pub const BRIGHT_FACTOR: f64 = 64.0;

/// The bright cells of one lighting: cell index (level `L`, Morton), `∫ L_c` over it and
/// the unit direction its light comes from.
#[derive(Clone, Debug, Default)]
pub struct BrightCells {
    pub cells: Vec<u32>,
    pub rgb: Vec<[f64; 3]>,
    pub dirs: Vec<Vec3>,
    /// Per cell, the directions of its shadow rays and how many of the [`AIMS`] equal
    /// shares of its light each stands for ([`Self::aim`]; empty before).
    pub aims: Vec<Vec<(Vec3, u8)>>,
}

fn luminance(c: &[f64; 3]) -> f64 {
    c.iter().zip(LUMINANCE).map(|(x, w)| x * w).sum()
}

impl BrightCells {
    /// Moves the bright cells of `cells` (zeroed there) into the result; `centroids` are
    /// the cells' luminance-weighted direction sums.
    pub fn split(cells: &mut [[f64; 3]], centroids: &[DVec3]) -> Self {
        let total: f64 = cells.iter().map(luminance).sum();
        let threshold = BRIGHT_FACTOR * total / cells.len() as f64;
        let mut bright: Vec<(f64, u32)> = cells
            .iter()
            .enumerate()
            .map(|(i, c)| (luminance(c), i as u32))
            .filter(|&(y, _)| y >= threshold && y > 0.0)
            .collect();
        bright.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        bright.truncate(MAX_BRIGHT);
        let mut out = Self::default();
        for (_, i) in bright {
            let d = centroids[i as usize];
            let length = d.length_squared();
            if length.is_nan() || length <= 0.0 {
                continue;
            }
            out.cells.push(i);
            out.rgb.push(cells[i as usize]);
            out.dirs.push(d.normalize().as_vec3());
            cells[i as usize] = [0.0; 3];
        }
        out
    }

    /// Chooses the directions of each cell's shadow rays ([`super::edges`]): the map's
    /// light in the cell, taken at the quantiles `(k + ½) / AIMS` of its luminance in
    /// texel order, each with the number of those `AIMS` shares it stands for (more than
    /// one where a direction is taken twice: a sun of one texel costs one ray).
    ///
    /// The light in a cell: texels at least as bright as the map's mean (the others hold
    /// under `1 / BRIGHT_FACTOR` of a bright cell's light), whole at their centres, or
    /// with `rotation` near a bright cell as 4x4 sub-texels at their turned directions, so
    /// that a turned sun's texel straddling two cells lends each its own part (as the
    /// projection splits it).
    pub fn aim(&mut self, env: &EnvMap, level: u32, rotation: Option<&DMat3>) {
        const SUB: u32 = 4;
        let res = env.resolution();
        let cells = 1u32 << level;
        let shift = 2 * (res.trailing_zeros() - level);
        let lums: Vec<f64> = env
            .texels()
            .iter()
            .map(|t| t.iter().zip(LUMINANCE).map(|(&c, w)| c as f64 * w).sum())
            .collect();
        let mean = lums.iter().sum::<f64>() / lums.len() as f64;
        let at: Vec<UVec2> = self.cells.iter().map(|&c| morton_decode(c)).collect();
        let bright_cell = |d: Vec3| {
            let t = texel_of(d, cells);
            self.cells
                .iter()
                .position(|&c| c == morton_encode(t.x, t.y))
        };
        let mut texels: Vec<Vec<(Vec3, f64)>> = vec![Vec::new(); self.cells.len()];
        for (i, &lum) in lums.iter().enumerate() {
            if lum < mean || lum <= 0.0 {
                continue;
            }
            let texel = UVec2::new(i as u32 % res, i as u32 / res);
            let centre = texel_center(texel, res);
            let Some(r) = rotation else {
                let cell = morton_encode(texel.x, texel.y) >> shift;
                if let Some(s) = self.cells.iter().position(|&c| c == cell) {
                    texels[s].push((centre, lum));
                }
                continue;
            };
            let d = (*r * centre.as_dvec3()).as_vec3();
            let t = texel_of(d, cells);
            let near = at
                .iter()
                .any(|c| c.x.abs_diff(t.x) <= 1 && c.y.abs_diff(t.y) <= 1);
            if !near {
                continue;
            }
            for k in 0..SUB * SUB {
                let sub = glam::Vec2::new(
                    texel.x as f32 + ((k % SUB) as f32 + 0.5) / SUB as f32,
                    texel.y as f32 + ((k / SUB) as f32 + 0.5) / SUB as f32,
                ) / res as f32;
                let d = (*r * square_to_sphere(sub).as_dvec3()).as_vec3();
                if let Some(s) = bright_cell(d) {
                    texels[s].push((d, lum / (SUB * SUB) as f64));
                }
            }
        }
        self.aims = texels
            .iter()
            .zip(&self.dirs)
            .map(|(list, &centroid)| {
                let total: f64 = list.iter().map(|t| t.1).sum();
                if total <= 0.0 {
                    // Only split shares of texels centred elsewhere: the centroid.
                    return vec![(centroid, AIMS as u8)];
                }
                let mut out: Vec<(Vec3, u8)> = Vec::with_capacity(AIMS);
                let (mut k, mut below) = (0, 0.0);
                for (j, &(d, lum)) in list.iter().enumerate() {
                    below += lum;
                    let last = j + 1 == list.len();
                    while k < AIMS && ((k as f64 + 0.5) / AIMS as f64 * total <= below || last) {
                        match out.last_mut() {
                            Some(o) if o.0 == d => o.1 += 1,
                            _ => out.push((d, 1)),
                        }
                        k += 1;
                    }
                }
                out
            })
            .collect();
    }

    /// True without bright cells.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Per record of `state`, bit `s` set when it sees bright cell `s` (level `level`),
    /// read record by record: the reference [`RecordColumns::masks`] is tested against.
    #[cfg(test)]
    pub fn record_masks(&self, state: &CacheState, level: u32) -> Vec<u8> {
        let store = state.store();
        let shift = 2 * (level - store.m());
        (0..store.len())
            .map(|i| {
                let bits = store.bits(i);
                self.cells.iter().enumerate().fold(0u8, |m, (s, &c)| {
                    m | ((bits.get((c >> shift) as usize) as u8) << s)
                })
            })
            .collect()
    }
}

/// The cache's visibility bits by direction: per block of 64 records, one word per
/// direction of the records' grid (bit `r` of the word: record `64 b + r` sees it).
///
/// A lighting change asks every record whether it sees each bright cell. Read record by
/// record that touches a cache line per record (garden's 295k records: 19 MB, 1.7 ms a
/// change); read by direction it touches one word per block and cell.
#[derive(Clone, Debug)]
pub struct RecordColumns {
    /// Resolution exponent of the records' grid.
    m: u32,
    /// Records covered.
    records: usize,
    /// `4^m` words per block of 64 records, blocks in record order.
    words: Vec<u64>,
}

impl RecordColumns {
    /// Bytes the columns of `records` records at resolution exponent `m` take.
    pub fn bytes_for(records: usize, m: u32) -> usize {
        8 * records.div_ceil(64) * (1 << (2 * m))
    }

    /// The columns of `state`'s records. Stops with [`crate::Error::Interrupted`] within a
    /// block of 64 records of the current [`Stop`] being set.
    pub fn of(state: &CacheState) -> Result<Self> {
        let store = state.store();
        let (m, records) = (store.m(), store.len());
        let directions = 1usize << (2 * m);
        let mut words = vec![0u64; records.div_ceil(64) * directions];
        let stop = Stop::current();
        words
            .par_chunks_mut(directions)
            .enumerate()
            .for_each(|(b, block)| {
                if stop.is_set() {
                    return;
                }
                for i in 64 * b..(64 * b + 64).min(records) {
                    let record = 1u64 << (i % 64);
                    for (k, &w) in store.bits(i).bit_words().iter().enumerate() {
                        let mut w = w;
                        while w != 0 {
                            block[64 * k + w.trailing_zeros() as usize] |= record;
                            w &= w - 1;
                        }
                    }
                }
            });
        stop.check("the records' columns")?;
        Ok(Self { m, records, words })
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> usize {
        8 * self.words.len()
    }

    /// Per record, bit `s` set when it sees `bright`'s cell `s` (level `level` >= the
    /// records' `m`).
    pub fn masks(&self, bright: &BrightCells, level: u32) -> Vec<u8> {
        let shift = 2 * (level - self.m);
        let directions = 1usize << (2 * self.m);
        let mut out = vec![0u8; self.records];
        out.par_chunks_mut(64)
            .zip(self.words.par_chunks(directions))
            .with_min_len(64)
            .for_each(|(masks, block)| {
                for (s, &c) in bright.cells.iter().enumerate() {
                    let w = block[(c >> shift) as usize];
                    for (r, m) in masks.iter_mut().enumerate() {
                        *m |= ((w >> r) as u8 & 1) << s;
                    }
                }
            });
        out
    }
}

/// Each pixel's kept records and their `β` (`n_keep` slots a pixel, heaviest first, unused
/// ones `β = 0`): `Ṽ` toward a bright cell as the cache's blend, or from the heaviest
/// record alone.
#[derive(Clone, Debug)]
pub struct PixelRecords {
    per_pixel: usize,
    ids: Vec<u32>,
    betas: Vec<f32>,
}

impl PixelRecords {
    /// The lookups of `points` (the transfer's), in parallel chunks of pixels (each pixel's
    /// slots are its own: the same for any thread count). Stops with
    /// [`crate::Error::Interrupted`] within a chunk of the current [`Stop`] being set.
    pub fn gather(
        points: &[Option<TransferPoint>],
        state: &CacheState,
        params: &CacheParams,
    ) -> Result<Self> {
        /// Pixels a task looks up between polls (a lookup is microseconds).
        const CHUNK: usize = 1024;
        let per_pixel = params.n_keep as usize;
        let mut ids = vec![0u32; per_pixel * points.len()];
        let mut betas = vec![0.0f32; per_pixel * points.len()];
        let stop = Stop::current();
        if per_pixel > 0 {
            ids.par_chunks_mut(per_pixel * CHUNK)
                .zip(betas.par_chunks_mut(per_pixel * CHUNK))
                .zip(points.par_chunks(CHUNK))
                .for_each(|((ids, betas), points)| {
                    if stop.is_set() {
                        return;
                    }
                    for (i, p) in points.iter().enumerate() {
                        let Some(p) = p else { continue };
                        let lookup = state.lookup_records(params, p.position, p.normal, p.radius);
                        for (k, n) in lookup.neighbours().iter().enumerate() {
                            ids[i * per_pixel + k] = n.id;
                            betas[i * per_pixel + k] = n.beta;
                        }
                    }
                });
        }
        stop.check("the pixels' records")?;
        Ok(Self {
            per_pixel,
            ids,
            betas,
        })
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> usize {
        8 * self.ids.len()
    }

    /// Bytes a pixel takes for a cache of `params`.
    pub fn bytes_per_pixel(params: &CacheParams) -> usize {
        8 * params.n_keep as usize
    }

    /// `Ṽ` of pixel `i` toward bright cell `s`: the blend `Σ β_k V_k`, or with `nearest`
    /// the heaviest record's `V`.
    pub fn visibility(&self, i: usize, s: usize, masks: &[u8], nearest: bool) -> f64 {
        let slots = i * self.per_pixel..(i + 1) * self.per_pixel;
        let (ids, betas) = (&self.ids[slots.clone()], &self.betas[slots]);
        let sees = |k: usize| betas[k] > 0.0 && masks[ids[k] as usize] >> s & 1 == 1;
        if nearest {
            return if sees(0) { 1.0 } else { 0.0 };
        }
        (0..ids.len())
            .filter(|&k| sees(k))
            .map(|k| betas[k] as f64)
            .sum()
    }

    /// `V` of pixel `i` toward bright cell `s` when its kept records agree on it (all see
    /// it: 1, none: 0); `None` where they disagree or the pixel kept none. (The tests'
    /// view of [`Self::seen`].)
    #[cfg(test)]
    pub fn agreed(&self, i: usize, s: usize, masks: &[u8]) -> Option<f64> {
        let (any, all) = self.seen(i, masks)?;
        match (any >> s & 1, all >> s & 1) {
            (_, 1) => Some(1.0),
            (0, _) => Some(0.0),
            _ => None,
        }
    }

    /// What pixel `i`'s kept records say of every bright cell at once: bit `s` of the
    /// first mask set where some record sees cell `s`, of the second where all do; `None`
    /// where the pixel kept no record.
    pub fn seen(&self, i: usize, masks: &[u8]) -> Option<(u8, u8)> {
        let slots = i * self.per_pixel..(i + 1) * self.per_pixel;
        let (ids, betas) = (&self.ids[slots.clone()], &self.betas[slots]);
        let (mut any, mut all, mut kept) = (0u8, u8::MAX, false);
        for (id, &beta) in ids.iter().zip(betas) {
            if beta > 0.0 {
                let m = masks[*id as usize];
                (any, all, kept) = (any | m, all & m, true);
            }
        }
        kept.then_some((any, all))
    }

    /// `Σ_s l_c(s) B(ω_s) cos θ_s Ṽ(ω_s)` of pixel `i`, shaded `at` (module docs), with
    /// `Ṽ` in the form `nearest` names, `masks` from [`RecordColumns::masks`].
    pub fn eval(
        &self,
        i: usize,
        at: &Shading,
        bright: &BrightCells,
        masks: &[u8],
        nearest: bool,
    ) -> [f64; 3] {
        bright.light(at, |s| self.visibility(i, s, masks, nearest))
    }
}

/// What the bright cells' light at a point depends on besides visibility.
#[derive(Clone, Copy, Debug)]
pub struct Shading {
    /// Unit normal facing the camera.
    pub normal: Vec3,
    /// Unit direction to the eye.
    pub wo: Vec3,
    pub material: Material,
}

impl BrightCells {
    /// `Σ_s l_c(s) B(ω_s) cos θ_s V(s)` shaded `at`, `V(s)` from `visibility` (called only
    /// for cells above the surface, and only where it returns > 0 is the BSDF evaluated).
    pub fn light(&self, at: &Shading, mut visibility: impl FnMut(usize) -> f64) -> [f64; 3] {
        let mut out = [0.0f64; 3];
        for s in 0..self.cells.len() {
            if at.normal.dot(self.dirs[s]) <= 0.0 {
                continue;
            }
            let v = visibility(s);
            if v > 0.0 {
                let l = self.light_of(at, s);
                for c in 0..3 {
                    out[c] += l[c] * v;
                }
            }
        }
        out
    }

    /// `l_c(s) B(ω_s) cos θ_s` shaded `at` (0 below the surface): cell `s`'s light where
    /// wholly visible. The BSDF enters by its luminance: the channel ratios scale `J`
    /// afterwards, as in the control variate.
    pub fn light_of(&self, at: &Shading, s: usize) -> [f64; 3] {
        let dir = self.dirs[s];
        let cos = at.normal.dot(dir);
        if cos <= 0.0 {
            return [0.0; 3];
        }
        let b = at.material.eval(at.normal, at.wo, dir) * cos;
        let y = LUMINANCE[0] * b.x as f64 + LUMINANCE[1] * b.y as f64 + LUMINANCE[2] * b.z as f64;
        self.rgb[s].map(|c| c * y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimators::preview::light::cell_integrals_and_centroids;
    use crate::lights::procedural::sky;

    /// A sun's cells leave the projection with their power and its direction; the rest of
    /// the map stays; a map without a concentrated light keeps every cell.
    #[test]
    fn split_takes_the_sun() {
        let sun = Vec3::new(0.3, 0.7, -0.4).normalize();
        let env = sky(sun, [5e4; 3], 1.0, [0.3, 0.5, 1.0], [0.9; 3], 256).unwrap();
        let (mut cells, centroids) = cell_integrals_and_centroids(&env, 6, None).unwrap();
        let before = cells.clone();
        let bright = BrightCells::split(&mut cells, &centroids);
        assert!(!bright.is_empty() && bright.cells.len() <= MAX_BRIGHT);
        let sun_power: f64 = bright.rgb.iter().map(|c| c[0]).sum();
        let total: f64 = before.iter().map(|c| c[0]).sum();
        assert!(sun_power > 0.5 * total, "{sun_power} of {total}");
        let kept: f64 = cells.iter().map(|c| c[0]).sum();
        assert!((kept + sun_power - total).abs() < 1e-9 * total);
        let d = bright.dirs[0];
        assert!(d.dot(sun) > (1.0f32).to_radians().cos(), "{d} vs {sun}");
        for (i, c) in bright.cells.iter().enumerate() {
            assert_eq!(cells[*c as usize], [0.0; 3]);
            assert_eq!(bright.rgb[i], before[*c as usize]);
        }
        let flat = crate::lights::envmap::EnvMap::constant([1.0; 3], 64).unwrap();
        let (mut cells, centroids) = cell_integrals_and_centroids(&flat, 6, None).unwrap();
        assert!(BrightCells::split(&mut cells, &centroids).is_empty());
    }

    /// A sun's shadow rays aim at its own texels: at most [`AIMS`] directions per cell,
    /// shares summing to one, each inside its cell and within the sun's disc, also when
    /// the map is turned; a light of one texel takes one ray.
    #[test]
    fn aims_share_each_cells_light() {
        let sun = Vec3::new(0.3, 0.7, -0.4).normalize();
        let env = sky(sun, [5e4; 3], 2.0, [0.3, 0.5, 1.0], [0.9; 3], 256).unwrap();
        for turn in [
            None,
            Some(crate::estimators::preview::light::rotation_about_y(70.0).unwrap()),
        ] {
            let (mut cells, centroids) =
                cell_integrals_and_centroids(&env, 6, turn.as_ref()).unwrap();
            let mut bright = BrightCells::split(&mut cells, &centroids);
            bright.aim(&env, 6, turn.as_ref());
            let turned = turn.map_or(sun, |r| (r * sun.as_dvec3()).as_vec3());
            assert_eq!(bright.aims.len(), bright.cells.len());
            for (aims, &cell) in bright.aims.iter().zip(&bright.cells) {
                assert!(!aims.is_empty() && aims.len() <= AIMS);
                assert_eq!(aims.iter().map(|a| a.1 as usize).sum::<usize>(), AIMS);
                for &(d, _) in aims {
                    let at = texel_of(d, 64);
                    assert_eq!(morton_encode(at.x, at.y), cell);
                    assert!(d.dot(turned) > 3f32.to_radians().cos(), "{d} vs {turned}");
                }
            }
        }
        let mut one = vec![[0.1f32; 3]; 64 * 64];
        one[64 * 20 + 30] = [1e5; 3];
        let env = EnvMap::from_octahedral(64, one).unwrap();
        let (mut cells, centroids) = cell_integrals_and_centroids(&env, 6, None).unwrap();
        let mut bright = BrightCells::split(&mut cells, &centroids);
        bright.aim(&env, 6, None);
        assert_eq!(
            bright.aims,
            vec![vec![(texel_center(UVec2::new(30, 20), 64), AIMS as u8)]]
        );
    }
}
