//! What orders the records a lookup gathers before it keeps the `m` nearest: squared
//! distance (CAM08 §5.1) or distance plus a normal term (survey eq. 6.3, the importance
//! cache's lookup). One index and one query serve both: the metric only changes the key
//! the candidates are sorted by.

use glam::Vec3;

/// How [`crate::spatial::SpatialIndex`]'s `m`-nearest query ranks the records within
/// `d_max` (and `θ_max`) of a lookup. Whatever the metric, the records it returns carry
/// their squared distance, so eq. 9's weights are unchanged.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Metric {
    /// `|x − p_i|²` (CAM08 §5.1; the same order as `|x − p_i|`).
    #[default]
    SquaredDistance,
    /// Survey eq. 6.3: `|x − p_i| + λ √(1 − n · n_i)`, world units; `λ >= 0` and finite
    /// (world units: how far a record may lie to count as much as a turn of the normal by
    /// 90°). `λ = 0` orders as [`Metric::SquaredDistance`].
    DistanceNormal { lambda: f32 },
}

impl Metric {
    /// The metric of a record at squared distance `d2` (`>= 0`, finite) whose normal has
    /// cosine `cos` with the lookup's: finite and `>= 0`, so its bits order as it does.
    #[inline]
    pub fn key(self, d2: f32, cos: f32) -> f32 {
        match self {
            Metric::SquaredDistance => d2,
            Metric::DistanceNormal { lambda } => {
                // A rounded cos a little above 1 is no turn at all.
                d2.sqrt() + lambda * (1.0 - cos).max(0.0).sqrt()
            }
        }
    }

    /// The value of eq. 6.3 between a lookup at `x` with unit normal `n` and a record at
    /// `p` with unit normal `m`, straight from the formula (for tests and callers that rank
    /// records themselves).
    pub fn between(self, x: Vec3, n: Vec3, p: Vec3, m: Vec3) -> f32 {
        self.key(x.distance_squared(p), n.dot(m))
    }

    /// Whether the metric's parameters are usable: `λ` finite and `>= 0`.
    pub fn is_valid(self) -> bool {
        match self {
            Metric::SquaredDistance => true,
            Metric::DistanceNormal { lambda } => lambda.is_finite() && lambda >= 0.0,
        }
    }
}

#[cfg(test)]
mod tests;
