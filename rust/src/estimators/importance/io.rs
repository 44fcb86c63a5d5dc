//! The importance cache's file: magic, version, the scene's geometry fingerprint, a hash
//! of the light set, the parameters and every record (position, normal, radius, rows F, U,
//! B: each a `u32` count of stored lights, `u32::MAX` for a dense row, then the sparse
//! row's light indices and its sums), little-endian. The lights are not written: [`ImportanceCache::load_for`] takes them
//! again and refuses a set whose hash differs, as it refuses another scene.

use std::path::Path;

use glam::Vec3;

use super::records::{ImportanceCache, ImportanceParams, ImportanceRecord, RowCdf};
use crate::error::{Error, Result};
use crate::geometry::Scene;
use crate::lights::vpl::{Vpl, VplSet};
use crate::sampling::rng::mix64;

const MAGIC: &[u8; 8] = b"VCIMPORT";
const VERSION: u32 = 2;

/// A row's count field for a dense row (one sum per light).
const DENSE: u32 = u32::MAX;

/// A hash of the lights' every field, in order.
pub fn lights_hash(lights: &[Vpl]) -> u64 {
    let mut h = mix64(lights.len() as u64);
    for v in lights {
        let text = format!("{v:?}");
        for chunk in text.as_bytes().chunks(8) {
            let mut b = [0u8; 8];
            b[..chunk.len()].copy_from_slice(chunk);
            h = mix64(h ^ u64::from_le_bytes(b));
        }
    }
    h
}

/// Reads little-endian values off a byte slice, failing (naming `path`) when it ends.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8]> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else {
            return Err(Error::invalid("path", "the cache file is truncated"));
        };
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().expect("4 bytes"),
        ))
    }

    fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }

    fn f32(&mut self) -> Result<f32> {
        Ok(f32::from_le_bytes(
            self.take(4)?.try_into().expect("4 bytes"),
        ))
    }

    fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }

    fn vec3(&mut self) -> Result<Vec3> {
        Ok(Vec3::new(self.f32()?, self.f32()?, self.f32()?))
    }

    /// A row over `n` lights ([`ImportanceCache::save`]'s form); sums that fall, or light
    /// indices out of order or range, are a corrupted file.
    fn row(&mut self, n: usize) -> Result<RowCdf> {
        let count = self.u32()?;
        let corrupted = || Error::invalid("path", "the cache file is corrupted");
        let row = if count == DENSE {
            RowCdf::Dense((0..n).map(|_| self.f32()).collect::<Result<_>>()?)
        } else {
            let count = count as usize;
            if count > n {
                return Err(corrupted());
            }
            let lights: Box<[u32]> = (0..count).map(|_| self.u32()).collect::<Result<_>>()?;
            let sums = (0..count).map(|_| self.f32()).collect::<Result<_>>()?;
            let ascending = lights.windows(2).all(|w| w[0] < w[1]);
            if !ascending || lights.last().is_some_and(|&k| k as usize >= n) {
                return Err(corrupted());
            }
            RowCdf::Sparse { lights, sums }
        };
        let sums = match &row {
            RowCdf::Dense(s) | RowCdf::Sparse { sums: s, .. } => s,
        };
        // Finite sums that never fall (the finite check follows in the caller).
        if sums.windows(2).any(|w| w[1] < w[0]) {
            return Err(corrupted());
        }
        Ok(row)
    }
}

impl ImportanceCache {
    /// Writes the cache to `path` atomically (module docs).
    pub fn save(&self, path: &Path) -> Result<()> {
        let state = self.read();
        let records = &state.index.records().records;
        let n = self.lights.len();
        let mut out = Vec::with_capacity(64 + records.len() * (40 + 12 * n));
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&VERSION.to_le_bytes());
        out.extend_from_slice(&self.scene.to_le_bytes());
        out.extend_from_slice(&lights_hash(&self.lights).to_le_bytes());
        out.extend_from_slice(&(n as u64).to_le_bytes());
        let p = self.params();
        out.extend_from_slice(&p.spacing.to_le_bytes());
        out.extend_from_slice(&p.nearest.to_le_bytes());
        out.extend_from_slice(&p.lam.to_le_bytes());
        for a in p.alpha {
            out.extend_from_slice(&a.to_le_bytes());
        }
        out.extend_from_slice(&(records.len() as u64).to_le_bytes());
        for r in records {
            for x in r.position.to_array().into_iter().chain(r.normal.to_array()) {
                out.extend_from_slice(&x.to_le_bytes());
            }
            out.extend_from_slice(&r.radius.to_le_bytes());
            for row in &r.rows {
                let sums = match row {
                    RowCdf::Dense(sums) => {
                        out.extend_from_slice(&DENSE.to_le_bytes());
                        sums
                    }
                    RowCdf::Sparse { lights, sums } => {
                        out.extend_from_slice(&(lights.len() as u32).to_le_bytes());
                        for k in lights.iter() {
                            out.extend_from_slice(&k.to_le_bytes());
                        }
                        sums
                    }
                };
                for x in sums.iter() {
                    out.extend_from_slice(&x.to_le_bytes());
                }
            }
        }
        crate::files::write_bytes_atomically(path, &out)
    }

    /// Reads a cache written by [`Self::save`] for `scene` lit by `lights` (the set it was
    /// built over); a truncated or foreign file, another scene or another set fails naming
    /// `path`, `scene` or `lights`.
    pub fn load_for(path: &Path, scene: &Scene, lights: &VplSet) -> Result<Self> {
        let bytes = std::fs::read(path)
            .map_err(|e| Error::invalid("path", format!("cannot read {}: {e}", path.display())))?;
        let mut r = Reader {
            bytes: &bytes,
            at: 0,
        };
        if r.take(8)? != MAGIC || r.u32()? != VERSION {
            return Err(Error::invalid("path", "not an importance cache file"));
        }
        let fingerprint = r.u64()?;
        if fingerprint != scene.geometry_fingerprint() {
            return Err(Error::invalid(
                "scene",
                "the cache was built for another scene (its geometry fingerprint differs)",
            ));
        }
        let hash = r.u64()?;
        let n = r.u64()? as usize;
        if n != lights.vpls.len() || hash != lights_hash(&lights.vpls) {
            return Err(Error::invalid(
                "lights",
                "are not the set the cache was built over",
            ));
        }
        let params = ImportanceParams {
            spacing: r.u32()?,
            nearest: r.u32()?,
            lam: r.f32()?,
            alpha: [r.f64()?, r.f64()?, r.f64()?, r.f64()?],
        };
        params
            .validate()
            .map_err(|e| Error::invalid("path", format!("corrupted parameters: {e}")))?;
        let cache = ImportanceCache::new(lights, params)?;
        let count = r.u64()?;
        {
            let mut state = cache.write();
            for _ in 0..count {
                let position = r.vec3()?;
                let normal = r.vec3()?;
                let radius = r.f32()?;
                let rows = [r.row(n)?, r.row(n)?, r.row(n)?];
                let ok = position.is_finite()
                    && (normal.length() - 1.0).abs() < 1e-3
                    && radius > 0.0
                    && rows.iter().all(RowCdf::is_finite);
                if !ok {
                    return Err(Error::invalid("path", "the cache file is corrupted"));
                }
                let rec = ImportanceRecord {
                    position,
                    normal,
                    radius,
                    rows,
                };
                state.index.admit(|set| {
                    set.records.push(rec);
                    Ok(set.records.len() - 1)
                })?;
                state.max_radius = state.max_radius.max(radius);
            }
        }
        if r.at != bytes.len() {
            return Err(Error::invalid("path", "the cache file has trailing bytes"));
        }
        Ok(cache)
    }
}
