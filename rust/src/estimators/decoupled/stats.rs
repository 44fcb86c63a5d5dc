//! The variance of binary visibility (SBF §3).

/// The variance of a binary variable of mean `m` (SBF §3: visibility is 0 or 1, so
/// `Var(V) = E[V](1 − E[V])`), clamped to `[0, 1/4]` for `m` outside `[0, 1]`.
pub fn binary_variance(m: f64) -> f64 {
    (m * (1.0 - m)).clamp(0.0, 0.25)
}
