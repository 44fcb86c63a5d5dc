//! The cache's file format, version 4 (all little-endian). Versions 1 (without the flags
//! word; read with `nearest_hits` on), 2 (without the scene fingerprint; read unbound) and 3
//! (without the default radius; read without one) are still read:
//!
//! | bytes | field |
//! |---|---|
//! | 8 | magic `b"VISCACHE"` |
//! | 4 | format version (`u32`, 4) |
//! | 60 | parameters: `M`, `n_startup` (`u32`); `d_max_scale`, `theta_max_deg`, `lambda_falloff` (`f32`); `m_search`, `n_keep` (`u32`); `w_min`, `delta_max`, `epsilon_max` (`f32`); `evict_worst`, `unused_frames`, `max_records` (`u32`); `pattern_seed` (`u64`); flags (`u32`: bit 0 `nearest_hits`, bit 1 `check_coherence`, bit 2 bound to a scene, bit 3 `emitters_visible`) |
//! | 4 | current frame (`u32`) |
//! | 8 | geometry fingerprint of the scene the cache is bound to (`u64`; 0 when unbound) |
//! | 4 | default lookup radius (`f32`, world units, finite and `>= 0`; NaN when unset) |
//! | 8 | record count `N` (`u64`) |
//! | 36 N | record headers: position `3 x f32`, normal `2 x u16`, `R_i` `f32`, misses, uses, last frame `u32`, `A` `u16`, reserved `u16` |
//! | 8 N W | map words (`u64`; `W = words_per_map(M)`: bits then hierarchy codes) |
//! | 8 | FNV-1a 64 checksum of everything before it |
//!
//! Loading checks the magic, the version, the exact length, the checksum, the parameters'
//! ranges, every header (finite position, `A` and `R_i` in range) and that every map's
//! hierarchy codes agree with its bits, so a truncated or corrupted file is an error that
//! names the file and what was wrong — never a panic or a half-loaded cache.

use std::path::Path;

use glam::Vec3;

use super::frames::LAST_FRAME;
use super::{CacheState, VisibilityCache};
use crate::error::{Error, Result};
use crate::geometry::Scene;
use crate::visibility::params::CacheParams;
use crate::visibility::record::{words_per_map, RecordHeader};

const MAGIC: &[u8; 8] = b"VISCACHE";
/// Version this build writes and reads.
pub const FORMAT_VERSION: u32 = 4;
const HEADER_BYTES: usize = 36;

/// FNV-1a 64 of `bytes`: the file's trailing checksum.
pub(super) fn checksum(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

impl VisibilityCache {
    /// The cache as bytes of the version-4 format (module docs).
    pub fn to_bytes(&self) -> Vec<u8> {
        let p = &self.params;
        let state = self.read();
        let m = p.log2_resolution;
        let n = state.len();
        let mut out = Vec::with_capacity(100 + n * (HEADER_BYTES + 8 * words_per_map(m)));
        out.extend_from_slice(MAGIC);
        let u32s =
            |out: &mut Vec<u8>, v: &[u32]| v.iter().for_each(|x| out.extend(x.to_le_bytes()));
        let f32s =
            |out: &mut Vec<u8>, v: &[f32]| v.iter().for_each(|x| out.extend(x.to_le_bytes()));
        u32s(&mut out, &[FORMAT_VERSION, m, p.n_startup]);
        f32s(
            &mut out,
            &[p.d_max_scale, p.theta_max_deg, p.lambda_falloff],
        );
        u32s(&mut out, &[p.m_search, p.n_keep]);
        f32s(&mut out, &[p.w_min, p.delta_max, p.epsilon_max]);
        u32s(&mut out, &[p.evict_worst, p.unused_frames, p.max_records]);
        out.extend(p.pattern_seed.to_le_bytes());
        u32s(
            &mut out,
            &[
                p.nearest_hits as u32
                    | (p.check_coherence as u32) << 1
                    | (state.scene.is_some() as u32) << 2
                    | (p.emitters_visible as u32) << 3,
                state.frame,
            ],
        );
        out.extend(state.scene.unwrap_or(0).to_le_bytes());
        f32s(&mut out, &[state.default_radius.unwrap_or(f32::NAN)]);
        out.extend((n as u64).to_le_bytes());
        for i in 0..n {
            let h = state.store().header(i);
            f32s(&mut out, &h.position);
            let (normal, ao) = h.quantised();
            out.extend(normal[0].to_le_bytes());
            out.extend(normal[1].to_le_bytes());
            f32s(&mut out, &[h.nearest_hit_distance]);
            u32s(&mut out, &[h.misses, h.uses, h.last_frame]);
            out.extend(ao.to_le_bytes());
            out.extend(0u16.to_le_bytes());
        }
        for i in 0..n {
            for w in state.store().bits(i).words() {
                out.extend(w.to_le_bytes());
            }
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
        if bytes.len() < MAGIC.len() || &bytes[..8] != MAGIC {
            return Err(bad("not a viscache_rs visibility cache (bad magic)".into()));
        }
        let mut r = Reader { bytes, at: 8 };
        let too_short = || bad(format!("truncated ({} bytes)", bytes.len()));
        let version = r.u32().ok_or_else(too_short)?;
        if !(1..=FORMAT_VERSION).contains(&version) {
            return Err(bad(format!(
                "format version {version}, this build reads {FORMAT_VERSION}"
            )));
        }
        let mut radius = None;
        let mut flags = 0;
        let mut fixed = || -> Option<(CacheParams, u32, u64, Option<u64>)> {
            let mut p = CacheParams::MEDIUM;
            p.log2_resolution = r.u32()?;
            p.n_startup = r.u32()?;
            p.d_max_scale = r.f32()?;
            p.theta_max_deg = r.f32()?;
            p.lambda_falloff = r.f32()?;
            p.m_search = r.u32()?;
            p.n_keep = r.u32()?;
            p.w_min = r.f32()?;
            p.delta_max = r.f32()?;
            p.epsilon_max = r.f32()?;
            p.evict_worst = r.u32()?;
            p.unused_frames = r.u32()?;
            p.max_records = r.u32()?;
            p.pattern_seed = r.u64()?;
            if version >= 2 {
                flags = r.u32()?;
            }
            let frame = r.u32()?;
            let scene = if version >= 3 { Some(r.u64()?) } else { None };
            if version >= 4 {
                radius = Some(r.f32()?);
            }
            let n = r.u64()?;
            Some((p, frame, n, scene))
        };
        let (mut params, frame, n, scene) = fixed().ok_or_else(too_short)?;
        // Every field is judged before anything is built, each error naming its field: a
        // corrupted word must not pass for a short file or reach a cache that misbehaves
        // later (a frame at the end of its range would wrap at the next `end_frame`).
        let defined = if version >= 3 { 0b1111 } else { 0b11 };
        if flags & !defined != 0 {
            return Err(bad(format!(
                "flags: {flags:#x} sets bits this format does not define (version {version} \
                 defines {defined:#06b})"
            )));
        }
        // Version 1 had no flags word: its caches keep the preset's (`nearest_hits` on).
        if version >= 2 {
            params.nearest_hits = flags & 1 == 1;
            params.check_coherence = flags & 2 == 2;
            params.emitters_visible = flags & 8 == 8;
        }
        let bound = flags & 4 == 4;
        if frame > LAST_FRAME {
            return Err(bad(format!(
                "frame: {frame} is out of range (0..={LAST_FRAME})"
            )));
        }
        let scene = scene.filter(|_| bound);
        let default_radius = match radius {
            Some(d) if d.is_nan() => None,
            Some(d) if !(d.is_finite() && d >= 0.0) => {
                return Err(bad(format!("default radius: {d} is not finite and >= 0")))
            }
            d => d,
        };
        params
            .validate()
            .map_err(|e| bad(format!("bad parameters: {e}")))?;
        if n > params.max_records as u64 {
            return Err(bad(format!(
                "record count: {n} exceeds max_records ({})",
                params.max_records
            )));
        }
        let words = words_per_map(params.log2_resolution);
        let record_bytes = (HEADER_BYTES + 8 * words) as u64;
        let expect = (r.at as u64 + 8).checked_add(n.saturating_mul(record_bytes));
        if expect != Some(bytes.len() as u64) {
            return Err(bad(format!(
                "{} bytes do not hold the {n} records the header announces ({} expected)",
                bytes.len(),
                expect.unwrap_or(u64::MAX)
            )));
        }
        let body = &bytes[..bytes.len() - 8];
        let stored = u64::from_le_bytes(bytes[bytes.len() - 8..].try_into().expect("8 bytes"));
        if checksum(body) != stored {
            return Err(bad("checksum mismatch: the file is corrupted".into()));
        }
        let n = n as usize;
        let headers_at = r.at;
        let words_at = headers_at + n * HEADER_BYTES;
        let cache = VisibilityCache::new(params)?;
        let mut state = CacheState::new(params.log2_resolution)?;
        state.frame = frame;
        state.scene = scene;
        state.default_radius = default_radius;
        let mut map = vec![0u64; words];
        for i in 0..n {
            let mut h = Reader {
                bytes,
                at: headers_at + i * HEADER_BYTES,
            };
            let position = [h.f32(), h.f32(), h.f32()].map(|v| v.expect("length checked"));
            let normal = [h.u16(), h.u16()].map(|v| v.expect("length checked"));
            let nearest = h.f32().expect("length checked");
            let counters = [h.u32(), h.u32(), h.u32()].map(|v| v.expect("length checked"));
            let ao = h.u16().expect("length checked");
            let reserved = h.u16().expect("length checked");
            let record = |reason: String| bad(format!("record {i}: {reason}"));
            if !Vec3::from(position).is_finite() {
                return Err(record(format!("position {position:?} is not finite")));
            }
            if nearest.is_nan() || nearest < 0.0 {
                return Err(record(format!(
                    "nearest-hit distance {nearest} is not >= 0"
                )));
            }
            let [misses, uses, last_frame] = counters;
            if misses > uses {
                return Err(record(format!("misses ({misses}) exceed uses ({uses})")));
            }
            if last_frame > frame {
                return Err(record(format!(
                    "last frame ({last_frame}) is after the cache's frame ({frame})"
                )));
            }
            if reserved != 0 {
                return Err(record(format!("reserved field {reserved} is not 0")));
            }
            let header = RecordHeader::from_quantised(position, normal, nearest, counters, ao);
            for (k, w) in map.iter_mut().enumerate() {
                let at = words_at + (i * words + k) * 8;
                *w = u64::from_le_bytes(bytes[at..at + 8].try_into().expect("length checked"));
            }
            state
                .push_packed(&params, header, &map)
                .map_err(|_| bad(format!("record {i}: map bits and hierarchy disagree")))?;
        }
        state.counters = Default::default();
        *cache.write() = state;
        Ok(cache)
    }

    /// Writes the cache to `path` (version-4 format, module docs), whole or not at all
    /// ([`crate::files::write_atomically`]).
    pub fn save(&self, path: &Path) -> Result<()> {
        crate::files::write_bytes_atomically(path, &self.to_bytes())
    }

    /// Reads a cache written by [`Self::save`] and binds it to `scene`
    /// ([`Self::bind_scene`]): a cache of other geometry is an error naming `scene` and the
    /// file.
    pub fn load_for(path: &Path, scene: &Scene) -> Result<Self> {
        let cache = Self::load(path)?;
        let f = scene.geometry_fingerprint();
        match cache.scene_fingerprint() {
            Some(bound) if bound != f => Err(Error::invalid(
                "scene",
                format!(
                    "the cache in {} {}",
                    path.display(),
                    super::other_scene(bound, f)
                ),
            )),
            _ => cache.bind_fingerprint(f).map(|()| cache),
        }
    }

    /// Reads a cache written by [`Self::save`].
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_bytes(&bytes, path)
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let s = self.bytes.get(self.at..self.at + N)?;
        self.at += N;
        s.try_into().ok()
    }
    fn u16(&mut self) -> Option<u16> {
        self.take().map(u16::from_le_bytes)
    }
    fn u32(&mut self) -> Option<u32> {
        self.take().map(u32::from_le_bytes)
    }
    fn u64(&mut self) -> Option<u64> {
        self.take().map(u64::from_le_bytes)
    }
    fn f32(&mut self) -> Option<f32> {
        self.take().map(f32::from_le_bytes)
    }
}
