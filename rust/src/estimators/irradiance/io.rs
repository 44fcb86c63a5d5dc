//! The irradiance cache's file format, version 1 (all little-endian):
//!
//! | bytes | field |
//! |---|---|
//! | 8 | magic `b"VCIRRADI"` |
//! | 4 | format version (`u32`, 1) |
//! | 32 | parameters: `a` (`f32`), `M`, `N` (`u32`), `r_min`, `r_max` (`f32`), gradients (`u32`: 0 none, 1 rotation, 2 both), `clamp_neighbours` (`u32`), `secondary_spp` (`u32`) |
//! | 8 | geometry fingerprint of the scene (`u64`; 0 when unbound) |
//! | 4 | default footprint (`f32`; NaN when unset) |
//! | 8 | record count `N` (`u64`) |
//! | 112 N | records: position, normal, `E` (3 x `f32` each), `R_i` (`f32`), `∇_r E` and `∇_t E` (3 x 3 `f32` each) |
//! | 8 | FNV-1a 64 checksum of everything before it |
//!
//! Loading checks magic, version, exact length, checksum, the parameters' ranges and every
//! record (finite position, unit normal, `E >= 0`, finite radius `> 0`, finite gradients),
//! so a truncated or corrupted file is an error naming the file, never a half-loaded cache.

use std::path::Path;

use glam::Vec3;

use super::cache::{Gradients, IrradianceCache, IrradianceParams};
use super::record::IrradianceRecord;
use crate::error::{Error, Result};
use crate::geometry::Scene;

const MAGIC: &[u8; 8] = b"VCIRRADI";
/// Version this build writes and reads.
pub const FORMAT_VERSION: u32 = 1;
const RECORD_FLOATS: usize = 28;

/// FNV-1a 64 of `bytes`.
pub(super) fn checksum(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

fn record_floats(r: &IrradianceRecord) -> [f32; RECORD_FLOATS] {
    let mut v = [0.0; RECORD_FLOATS];
    v[0..3].copy_from_slice(&r.position.to_array());
    v[3..6].copy_from_slice(&r.normal.to_array());
    v[6..9].copy_from_slice(&r.irradiance);
    v[9] = r.radius;
    for c in 0..3 {
        v[10 + 3 * c..13 + 3 * c].copy_from_slice(&r.rotation[c].to_array());
        v[19 + 3 * c..22 + 3 * c].copy_from_slice(&r.translation[c].to_array());
    }
    v
}

/// The record of `v`, or why it is not one.
fn record_of(v: &[f32]) -> std::result::Result<IrradianceRecord, String> {
    let vec = |i: usize| Vec3::new(v[i], v[i + 1], v[i + 2]);
    let r = IrradianceRecord {
        position: vec(0),
        normal: vec(3),
        irradiance: [v[6], v[7], v[8]],
        radius: v[9],
        rotation: [vec(10), vec(13), vec(16)],
        translation: [vec(19), vec(22), vec(25)],
    };
    check_record(&r)?;
    Ok(r)
}

/// Why `r` is not a record the cache can hold, if it is not.
pub(super) fn check_record(r: &IrradianceRecord) -> std::result::Result<(), String> {
    if !r.position.is_finite() {
        return Err("a non-finite position".into());
    }
    if !(r.normal.is_finite() && (r.normal.length() - 1.0).abs() < 1e-3) {
        return Err(format!("a normal that is not unit ({})", r.normal));
    }
    if !r.irradiance.iter().all(|e| e.is_finite() && *e >= 0.0) {
        return Err(format!(
            "irradiance {:?} (must be finite and >= 0)",
            r.irradiance
        ));
    }
    if !(r.radius.is_finite() && r.radius > 0.0) {
        return Err(format!("radius {} (must be finite and > 0)", r.radius));
    }
    if !r
        .rotation
        .iter()
        .chain(&r.translation)
        .all(|g| g.is_finite())
    {
        return Err("a non-finite gradient".into());
    }
    Ok(())
}

impl IrradianceCache {
    /// The cache as bytes of the version-1 format (module docs).
    pub fn to_bytes(&self) -> Vec<u8> {
        let p = self.params();
        let state = self.read();
        let records = state.records();
        let mut out = Vec::with_capacity(80 + records.len() * 4 * RECORD_FLOATS);
        out.extend_from_slice(MAGIC);
        let u32s =
            |out: &mut Vec<u8>, v: &[u32]| v.iter().for_each(|x| out.extend(x.to_le_bytes()));
        let f32s =
            |out: &mut Vec<u8>, v: &[f32]| v.iter().for_each(|x| out.extend(x.to_le_bytes()));
        u32s(&mut out, &[FORMAT_VERSION]);
        f32s(&mut out, &[p.a]);
        u32s(&mut out, &[p.strata.0, p.strata.1]);
        f32s(&mut out, &[p.r_min, p.r_max]);
        let gradients = Gradients::ALL
            .iter()
            .position(|g| *g == p.gradients)
            .unwrap_or(2);
        u32s(
            &mut out,
            &[gradients as u32, p.clamp_neighbours as u32, p.secondary_spp],
        );
        out.extend(state.scene.unwrap_or(0).to_le_bytes());
        f32s(&mut out, &[state.default_footprint.unwrap_or(f32::NAN)]);
        out.extend((records.len() as u64).to_le_bytes());
        for r in records {
            f32s(&mut out, &record_floats(r));
        }
        let sum = checksum(&out);
        out.extend(sum.to_le_bytes());
        out
    }

    /// Reads a cache written by [`Self::to_bytes`]; `source` names the input in errors.
    pub fn from_bytes(bytes: &[u8], source: &Path) -> Result<Self> {
        let bad = |reason: String| Error::Parse {
            path: source.to_path_buf(),
            reason,
        };
        if bytes.len() < 8 || &bytes[..8] != MAGIC {
            return Err(bad("not a viscache_rs irradiance cache (bad magic)".into()));
        }
        const FIXED: usize = 8 + 4 + 32 + 8 + 4 + 8;
        if bytes.len() < FIXED + 8 {
            return Err(bad(format!("truncated ({} bytes)", bytes.len())));
        }
        let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
        let f32_at = |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
        let u64_at = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
        let version = u32_at(8);
        if version != FORMAT_VERSION {
            return Err(bad(format!(
                "format version {version}, this build reads {FORMAT_VERSION}"
            )));
        }
        let count = u64_at(FIXED - 8);
        let expected = (count as u128) * (4 * RECORD_FLOATS) as u128 + (FIXED + 8) as u128;
        if bytes.len() as u128 != expected {
            return Err(bad(format!(
                "{} bytes, expected {expected} for {count} records (truncated or padded)",
                bytes.len()
            )));
        }
        let body = bytes.len() - 8;
        if checksum(&bytes[..body]) != u64_at(body) {
            return Err(bad("checksum mismatch (corrupted)".into()));
        }
        let gradients = *Gradients::ALL
            .get(u32_at(32) as usize)
            .ok_or_else(|| bad(format!("gradients code {}", u32_at(32))))?;
        let params = IrradianceParams {
            a: f32_at(12),
            strata: (u32_at(16), u32_at(20)),
            r_min: f32_at(24),
            r_max: f32_at(28),
            gradients,
            clamp_neighbours: match u32_at(36) {
                0 => false,
                1 => true,
                v => return Err(bad(format!("clamp_neighbours flag {v}"))),
            },
            secondary_spp: u32_at(40),
        };
        params
            .validate()
            .map_err(|e| bad(format!("parameters out of range: {e}")))?;
        let fingerprint = u64_at(44);
        let footprint = f32_at(52);
        let footprint = if footprint.is_nan() {
            None
        } else if footprint.is_finite() && footprint > 0.0 {
            Some(footprint)
        } else {
            return Err(bad(format!("default footprint {footprint}")));
        };
        let floats: Vec<f32> = bytes[FIXED..body]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        let mut records = Vec::with_capacity(count as usize);
        for (i, v) in floats.chunks_exact(RECORD_FLOATS).enumerate() {
            records.push(record_of(v).map_err(|why| bad(format!("record {i}: {why}")))?);
        }
        IrradianceCache::with_state(params, |state| {
            state.scene = (fingerprint != 0).then_some(fingerprint);
            state.default_footprint = footprint;
            state.restore(records);
            Ok(())
        })
    }

    /// Writes the cache to `path` (through a temporary file renamed into place).
    pub fn save(&self, path: &Path) -> Result<()> {
        crate::files::write_bytes_atomically(path, &self.to_bytes())
    }

    /// Reads a cache written by [`Self::save`] for `scene`: a cache bound to another
    /// geometry is refused with an error naming `cache`.
    pub fn load_for(path: &Path, scene: &Scene) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let cache = Self::from_bytes(&bytes, path)?;
        cache.bind_scene(scene)?;
        Ok(cache)
    }
}
