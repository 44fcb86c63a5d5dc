//! Visibility cache parameters (CAM08 §5.4, Table 1) with `const fn` presets for low,
//! medium and high scene complexity.
//!
//! Table 1 sorts the parameters by what they control: initialisation (`N_startup`),
//! search (`d_max`, `θ_max`), insertion (`w_min`, `δ̄_max`) and removal (`ε_max`). This
//! struct adds the ones the paper fixes in the text: the record resolution `M` (§5.5), the
//! candidate count `m` and kept count `n` (§5.1), `λ` of eq. 9, the unused-frame limit `F`
//! (§5.3), and a hard `max_records` cap. `d_max` is not a constant: it is `k` times the
//! pixel's footprint at the query point (§5.1, after [TL04]), so `k` is the parameter.
//!
//! The presets differ only in how densely the cache refines: a complex scene (many small
//! occluders) wants a higher `w_min`, a lower `δ̄_max` and a stricter `ε_max`. The paper
//! leaves the values to the user; ours were chosen on the built-in scenes at 256 x 192,
//! and every one can be overridden. Two facts guided them:
//!
//! - Normalised by `w_lo`, a record at the full distance `d_max` with an equal normal still
//!   weighs `ŵ ≈ 0.45` (`θ_max = 30°`, `λ = 5`), so `w_min` below that only inserts where
//!   no record is in range at all; `w_min = 0.5` keeps a record within about `0.7 d_max` of
//!   every point (on flat ground, normals equal), `0.55` within `0.43 d_max`, `0.6` within
//!   `0.31 d_max`.
//! - Half of every map is below the tangent plane and always 0, so `δ̄` lives in
//!   `[0, 0.5]`; neighbouring records on open ground typically differ by `δ̄ ≈ 0.01`
//!   (open Cornell box, 256 x 192), near contact shadows by up to 0.02 and more. A
//!   `δ̄_max` of 0.02 refines where occluders are close; 0.05 rarely fires.
//! - `k = 12` footprints is CAM08's "5% of the image width" at 256 pixels across; for the
//!   same world-space density at width `W`, use `k = 0.05 W`.

use crate::error::{Error, Result};
use crate::sampling::pattern::{
    check_log2_resolution, DEFAULT_LOG2_RESOLUTION, DEFAULT_PATTERN_SEED,
};
pub use crate::spatial::weight::{normal_angle, raw_weight};
use crate::spatial::{Metric, Weighting, MAX_KEEP, MAX_NEAREST};
use crate::visibility::record::RecordTracing;

/// Largest `m` (candidates per lookup). Lookups keep candidates on the stack.
pub const MAX_SEARCH_COUNT: u32 = MAX_NEAREST as u32;

/// Largest `n` (records kept per lookup; CAM08 uses 3–4).
pub const MAX_KEEP_COUNT: u32 = MAX_KEEP as u32;

/// Largest `max_records`: record ids are `u32` and the kd-tree indexes with `u32`.
pub const MAX_RECORDS_LIMIT: u32 = 1 << 28;

/// Everything that steers a [`crate::visibility::cache::VisibilityCache`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CacheParams {
    /// `M`: records hold `2^M x 2^M` directions, `M` in `1..=7` (§5.5; default 5).
    pub log2_resolution: u32,
    /// `N_startup`: records bootstrapped at first hits spread over the image (§5, default
    /// 1000). `0` skips the bootstrap.
    pub n_startup: u32,
    /// `k`: the search radius is `d_max = k · footprint`, footprint = square root of the
    /// pixel's area projected on the query's tangent plane (world units). `> 0`.
    pub d_max_scale: f32,
    /// `θ_max`, degrees in `[0, 180]`: records whose normal differs by `θ_i >= θ_max` are
    /// ignored (§5.1; default 30°).
    pub theta_max_deg: f32,
    /// `λ >= 0` of eq. 9: how steeply the weight falls off near `d = 0` (default 5).
    pub lambda_falloff: f32,
    /// `m`: nearest records examined per lookup, `1..=64` (default 16).
    pub m_search: u32,
    /// `n`: best-weighted records kept and blended, `1..=min(m, 16)` (default 4).
    pub n_keep: u32,
    /// `w_min` in `[0, 1]`: insert when the best weight `max w_i` is below it (§5.2).
    pub w_min: f32,
    /// `δ̄_max` in `[0, 1]`: insert when the mean pairwise eq. 11 difference of the kept
    /// records exceeds it (§5.2).
    pub delta_max: f32,
    /// `ε_max` in `[0, 1]`: at the end of a frame, remove records whose miss rate over that
    /// frame's uses exceeds it (§5.3).
    pub epsilon_max: f32,
    /// Alternative removal (§5.3): when `> 0`, remove instead the `evict_worst` records
    /// with the highest miss rate (among those with misses) each frame.
    pub evict_worst: u32,
    /// `F >= 1`: remove records not used for this many frames (§5.3; default 10).
    pub unused_frames: u32,
    /// Hard cap on the number of records, `1..=2^28`: insertions beyond it are refused.
    pub max_records: u32,
    /// Seed of the per-texel direction pattern (§5.5); `0` is the shared default pattern.
    pub pattern_seed: u64,
    /// Whether records find `R_i`, the distance to the nearest hit (§6.1), with closest-hit
    /// rays on their occluded directions (about as many rays again). Only ambient
    /// occlusion's insertion criterion reads it; caches for the control variate can skip it
    /// (`R_i` is then `inf`, which that criterion ignores).
    pub nearest_hits: bool,
    /// Whether an empty cache's build first checks that records would pay
    /// ([`crate::visibility::cache::coherence`]): it traces 16 x 16 visibility maps at pairs
    /// of pixels as far apart as the records will be (`sqrt(covered pixels / record_cap)`),
    /// predicts from them the control variate's variance over product sampling's, weighs
    /// that against the records' cost for the samples they will serve
    /// ([`crate::visibility::cache::VisibilityCache::plan_samples`]), and inserts no record
    /// when the predicted gain is below 1 (the control variate then samples as plain
    /// product sampling, for the check's few rays). Nor does it when none of the check's
    /// rays sees the map (a closed room lit by its own lights): records would all be zero
    /// and cancel nothing (`BuildReport::blind`). A build that passes the check stops
    /// inserting at [`record_cap`] records: past a tenth of the view's pixels, records
    /// barely help the control variate and cost most of the build.
    pub check_coherence: bool,
    /// Whether a record's ray that reaches an area light before anything else counts as
    /// unoccluded ([`crate::visibility::record::RecordTracing::emitters_visible`]): records
    /// then hold the lights' visibility, which the relighter's area lights read
    /// ([`crate::estimators::decoupled`]). Off (every preset), a light's own triangles
    /// occlude like any surface: the sky's visibility, which the control variate and the
    /// relighter's map need.
    pub emitters_visible: bool,
}

/// Records per covered pixel at which a checked build stops inserting ([`record_cap`]).
pub const RECORD_SHARE_LIMIT: f64 = 0.1;

/// Records a checked build always may insert, however small the view.
pub const MIN_RECORD_CAP: usize = 1024;

/// The most records a build over `covered_pixels` may hold with `params`:
/// `max_records`, and with [`CacheParams::check_coherence`] also
/// `max(RECORD_SHARE_LIMIT · covered_pixels, MIN_RECORD_CAP)`. Measured at 160x120, capping
/// at a tenth of the pixels kept the control variate's variance within 3% of the uncapped
/// cache's (hairball 0.79 against 0.77, instances 0.84 / 0.82, meshes 0.56 / 0.55) for a
/// quarter to a fifth of the build's rays.
pub fn record_cap(params: &CacheParams, covered_pixels: usize) -> usize {
    let max = params.max_records as usize;
    if params.check_coherence {
        let share = (RECORD_SHARE_LIMIT * covered_pixels as f64).ceil() as usize;
        max.min(share.max(MIN_RECORD_CAP))
    } else {
        max
    }
}

/// Pixel pairs the coherence check traces.
pub const COHERENCE_PAIRS: usize = 64;

/// `M` of the coherence check's visibility maps (16 x 16 directions).
pub const COHERENCE_LOG2_RESOLUTION: u32 = 4;

impl CacheParams {
    /// Simple scenes: few, large occluders. Sparse records, tolerant thresholds.
    pub const LOW: Self = Self {
        w_min: 0.5,
        delta_max: 0.04,
        epsilon_max: 0.08,
        n_startup: 500,
        max_records: 200_000,
        ..Self::MEDIUM
    };

    /// The default (§5.4's "reasonable default values": `N_startup = 1000`, `θ_max = 30°`,
    /// `λ = 5`, `m = 16`, `n = 4`, `ε_max = 5%`, `F = 10`).
    pub const MEDIUM: Self = Self {
        log2_resolution: DEFAULT_LOG2_RESOLUTION,
        n_startup: 1000,
        d_max_scale: 12.0,
        theta_max_deg: 30.0,
        lambda_falloff: 5.0,
        m_search: 16,
        n_keep: 4,
        w_min: 0.55,
        delta_max: 0.02,
        epsilon_max: 0.05,
        evict_worst: 0,
        unused_frames: 10,
        max_records: 500_000,
        pattern_seed: DEFAULT_PATTERN_SEED,
        nearest_hits: true,
        check_coherence: false,
        emitters_visible: false,
    };

    /// Complex occlusion (foliage, many small parts): dense records, strict thresholds.
    pub const HIGH: Self = Self {
        w_min: 0.6,
        delta_max: 0.012,
        epsilon_max: 0.03,
        n_startup: 2000,
        max_records: 2_000_000,
        ..Self::MEDIUM
    };

    /// The default: chosen by measurement over the built-in and benchmark scenes for the
    /// control variate's efficiency with its build included (benches/README.md): 64²
    /// records (the garage's light through thin gaps needs them: relMSE at equal samples
    /// halves against 32²), `LOW`'s sparse insertion, no nearest-hit rays, and the
    /// coherence check, which leaves incoherent scenes (dense grass) without records.
    pub const AUTO: Self = Self {
        log2_resolution: 6,
        nearest_hits: false,
        check_coherence: true,
        ..Self::LOW
    };

    /// How the cache's records trace their rays.
    pub const fn record_tracing(&self) -> RecordTracing {
        RecordTracing {
            nearest_hits: self.nearest_hits,
            emitters_visible: self.emitters_visible,
        }
    }

    /// The preset called `name` (`"auto"`, `"low"`, `"medium"`, `"high"`).
    pub fn preset(name: &str) -> Result<Self> {
        match name {
            "auto" => Ok(Self::AUTO),
            "low" => Ok(Self::LOW),
            "medium" => Ok(Self::MEDIUM),
            "high" => Ok(Self::HIGH),
            _ => Err(Error::invalid(
                "preset",
                format!("must be 'auto', 'low', 'medium' or 'high', got {name:?}"),
            )),
        }
    }

    /// This preset with another resolution exponent `M`.
    pub const fn with_log2_resolution(mut self, m: u32) -> Self {
        self.log2_resolution = m;
        self
    }

    /// `θ_max` in radians.
    pub fn theta_max(&self) -> f32 {
        self.theta_max_deg.to_radians()
    }

    /// Checks every range; the error names the offending parameter.
    pub fn validate(&self) -> Result<()> {
        check_log2_resolution(self.log2_resolution)
            .map_err(|_| range("log2_resolution", "be in 1..=7", self.log2_resolution))?;
        let unit = |name: &str, v: f32| {
            if (0.0..=1.0).contains(&v) {
                Ok(())
            } else {
                Err(range(name, "be in [0, 1]", v))
            }
        };
        if !(self.d_max_scale.is_finite() && self.d_max_scale > 0.0) {
            return Err(range("d_max_scale", "be finite and > 0", self.d_max_scale));
        }
        if !(0.0..=180.0).contains(&self.theta_max_deg) {
            return Err(range("theta_max_deg", "be in [0, 180]", self.theta_max_deg));
        }
        if !(self.lambda_falloff.is_finite() && self.lambda_falloff >= 0.0) {
            return Err(range(
                "lambda_falloff",
                "be finite and >= 0",
                self.lambda_falloff,
            ));
        }
        if !(1..=MAX_SEARCH_COUNT).contains(&self.m_search) {
            return Err(range("m_search", "be in 1..=64", self.m_search));
        }
        if !(1..=self.m_search.min(MAX_KEEP_COUNT)).contains(&self.n_keep) {
            return Err(range(
                "n_keep",
                &format!("be in 1..=min(m_search, 16) ({})", self.m_search.min(16)),
                self.n_keep,
            ));
        }
        unit("w_min", self.w_min)?;
        unit("delta_max", self.delta_max)?;
        unit("epsilon_max", self.epsilon_max)?;
        if self.unused_frames == 0 {
            return Err(range("unused_frames", "be >= 1", self.unused_frames));
        }
        if !(1..=MAX_RECORDS_LIMIT).contains(&self.max_records) {
            return Err(range(
                "max_records",
                "be in 1..=268435456",
                self.max_records,
            ));
        }
        Ok(())
    }

    /// `w_lo` of eq. 9: the weight of a record at `d = d_max` and `θ = θ_max`, the smallest
    /// one a lookup can accept; `ŵ = (w − w_lo) / (1 − w_lo)` maps `[w_lo, 1]` to `[0, 1]`.
    pub fn weight_floor(&self) -> f32 {
        raw_weight(1.0, self.theta_max(), self.lambda_falloff)
    }

    /// What the record index needs of these parameters to gather and score a lookup's
    /// `m` nearest records.
    pub fn weighting(&self) -> Weighting {
        Weighting {
            m: self.m_search as usize,
            theta_max: self.theta_max(),
            w_lo: self.weight_floor(),
            lambda: self.lambda_falloff,
            metric: Metric::SquaredDistance,
        }
    }
}

impl Default for CacheParams {
    fn default() -> Self {
        Self::MEDIUM
    }
}

fn range(name: &str, what: &str, got: impl std::fmt::Display) -> Error {
    Error::invalid(name, format!("must {what}, got {got}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_ordered_by_density() {
        for p in [CacheParams::LOW, CacheParams::MEDIUM, CacheParams::HIGH] {
            p.validate().unwrap();
        }
        let (l, m, h) = (CacheParams::LOW, CacheParams::MEDIUM, CacheParams::HIGH);
        assert!(l.w_min < m.w_min && m.w_min < h.w_min);
        assert!(l.delta_max > m.delta_max && m.delta_max > h.delta_max);
        assert!(l.epsilon_max > m.epsilon_max && m.epsilon_max > h.epsilon_max);
        assert_eq!(
            CacheParams::preset("medium").unwrap(),
            CacheParams::default()
        );
        assert!(CacheParams::preset("huge").is_err());
    }

    #[test]
    fn validation_names_the_parameter() {
        let cases: [(&str, CacheParams); 9] = [
            (
                "log2_resolution",
                CacheParams::MEDIUM.with_log2_resolution(8),
            ),
            (
                "d_max_scale",
                CacheParams {
                    d_max_scale: f32::NAN,
                    ..CacheParams::MEDIUM
                },
            ),
            (
                "theta_max_deg",
                CacheParams {
                    theta_max_deg: 181.0,
                    ..CacheParams::MEDIUM
                },
            ),
            (
                "lambda_falloff",
                CacheParams {
                    lambda_falloff: -1.0,
                    ..CacheParams::MEDIUM
                },
            ),
            (
                "m_search",
                CacheParams {
                    m_search: 0,
                    ..CacheParams::MEDIUM
                },
            ),
            (
                "n_keep",
                CacheParams {
                    n_keep: 17,
                    ..CacheParams::MEDIUM
                },
            ),
            (
                "w_min",
                CacheParams {
                    w_min: 1.5,
                    ..CacheParams::MEDIUM
                },
            ),
            (
                "unused_frames",
                CacheParams {
                    unused_frames: 0,
                    ..CacheParams::MEDIUM
                },
            ),
            (
                "max_records",
                CacheParams {
                    max_records: 0,
                    ..CacheParams::MEDIUM
                },
            ),
        ];
        for (name, p) in cases {
            let e = p.validate().unwrap_err().to_string();
            assert!(e.starts_with(name), "{name}: {e}");
        }
    }

    #[test]
    fn normal_angle_matches_atan2_to_f32_rounding() {
        let mut worst = 0.0f64;
        for k in 0..=20_000 {
            let phi = std::f64::consts::PI * k as f64 / 20_000.0;
            for r in [1.0f64, 0.5, 1e-3] {
                let (s, c) = ((r * phi.sin()) as f32, (r * phi.cos()) as f32);
                let want = (s as f64).atan2(c as f64);
                worst = worst.max((normal_angle(s, c) as f64 - want).abs());
            }
        }
        assert!(worst < 4e-7, "worst error {worst:e} rad");
        assert_eq!(normal_angle(0.0, 1.0), 0.0);
        assert_eq!(normal_angle(0.0, 0.0), 0.0);
        assert_eq!(normal_angle(0.0, -1.0), std::f32::consts::PI);
        assert!(normal_angle(f32::NAN, 1.0).is_nan());
    }

    #[test]
    fn weight_floor_is_eq9_at_the_search_limits() {
        let p = CacheParams::MEDIUM;
        let expect = (1.0 - 30.0 / 180.0) * (1.0 - 1.0 / 6.0);
        assert!((p.weight_floor() - expect).abs() < 1e-6);
        assert_eq!(raw_weight(0.0, 0.0, 5.0), 1.0);
        let wide = CacheParams {
            theta_max_deg: 180.0,
            ..p
        };
        assert!(wide.weight_floor().abs() < 1e-6);
    }

    #[test]
    fn checked_builds_cap_records_at_a_tenth_of_the_pixels() {
        let auto = CacheParams::AUTO;
        assert!(auto.check_coherence && !CacheParams::MEDIUM.check_coherence);
        assert_eq!(record_cap(&auto, 100_000), 10_000);
        assert_eq!(record_cap(&auto, 100_001), 10_001);
        // Small views keep the floor; max_records still bounds everything.
        assert_eq!(record_cap(&auto, 1_728), MIN_RECORD_CAP);
        let small = CacheParams {
            max_records: 500,
            ..auto
        };
        assert_eq!(record_cap(&small, 100_000), 500);
        let unchecked = CacheParams::MEDIUM;
        assert_eq!(
            record_cap(&unchecked, 100_000),
            unchecked.max_records as usize
        );
    }
}
