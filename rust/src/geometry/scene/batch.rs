//! Batches of rays as the bindings pass them, their checks, and closest-hit results.

use rayon::prelude::*;

use crate::error::{Error, Result};

/// Upper ends of the ray segments of a batch.
#[derive(Clone, Copy, Debug)]
pub enum TMax<'a> {
    /// One value for every ray (may be `inf`).
    Scalar(f32),
    /// One value per ray.
    PerRay(&'a [f32]),
}

/// A batch of rays `origin + t direction`, `t` in `[0, tmax)`.
#[derive(Clone, Copy, Debug)]
pub struct RayBatch<'a> {
    pub origins: &'a [[f32; 3]],
    pub directions: &'a [[f32; 3]],
    pub tmax: TMax<'a>,
}

impl<'a> RayBatch<'a> {
    /// Rays with an unbounded segment.
    pub fn new(origins: &'a [[f32; 3]], directions: &'a [[f32; 3]]) -> Self {
        Self {
            origins,
            directions,
            tmax: TMax::Scalar(f32::INFINITY),
        }
    }

    /// Number of rays.
    pub fn len(&self) -> usize {
        self.origins.len()
    }

    /// True for a batch of no rays.
    pub fn is_empty(&self) -> bool {
        self.origins.is_empty()
    }

    #[inline(always)]
    pub(super) fn tmax_of(&self, i: usize) -> f32 {
        match self.tmax {
            TMax::Scalar(t) => t,
            TMax::PerRay(t) => t[i],
        }
    }

    /// Checks lengths, finiteness, directions of a representable length (see
    /// [`MIN_DIRECTION_LENGTH`]) and `tmax >= 0` (NaN rejected).
    /// Costs a few percent of tracing the batch: fixed chunks are scanned in parallel with
    /// a branch-free test and only a failing chunk is searched for its first bad row.
    pub fn validate(&self) -> Result<()> {
        self.validate_shape()?;
        let first = first_where(self.origins, bad_origin)
            .map(|i| (BadArgument::Origins, i))
            .or_else(|| {
                first_where(self.directions, bad_direction).map(|i| (BadArgument::Directions, i))
            })
            .or_else(|| match self.tmax {
                TMax::PerRay(t) => first_where(t, |v| bad_tmax(*v)).map(|i| (BadArgument::Tmax, i)),
                TMax::Scalar(_) => None,
            });
        first.map_or(Ok(()), |bad| Err(self.error_at(bad)))
    }

    /// The checks of [`Self::validate`] that do not read the rays: as many directions and
    /// `tmax` values (when not one for all) as origins, and a valid scalar `tmax`.
    pub fn validate_shape(&self) -> Result<()> {
        let n = self.origins.len();
        if self.directions.len() != n {
            return Err(Error::invalid(
                "directions",
                format!("has {} rows but origins has {n}", self.directions.len()),
            ));
        }
        match self.tmax {
            TMax::Scalar(t) if bad_tmax(t) => {
                Err(Error::invalid("tmax", format!("must be >= 0, got {t}")))
            }
            TMax::PerRay(t) if t.len() != n => Err(Error::invalid(
                "tmax",
                format!("has {} values but there are {n} rays", t.len()),
            )),
            _ => Ok(()),
        }
    }

    /// The first bad row among rays `range` (of a batch whose shape
    /// [`Self::validate_shape`] accepted), as [`Self::validate`] orders them: origins, then
    /// directions, then `tmax`. The least over ranges is the batch's first.
    #[inline]
    pub fn first_bad(&self, range: std::ops::Range<usize>) -> Option<(BadArgument, usize)> {
        let at = |argument| move |i| (argument, range.start + i);
        first_in(&self.origins[range.clone()], bad_origin)
            .map(at(BadArgument::Origins))
            .or_else(|| {
                first_in(&self.directions[range.clone()], bad_direction)
                    .map(at(BadArgument::Directions))
            })
            .or_else(|| match self.tmax {
                TMax::PerRay(t) => {
                    first_in(&t[range.clone()], |v| bad_tmax(*v)).map(at(BadArgument::Tmax))
                }
                TMax::Scalar(_) => None,
            })
    }

    /// The error for a bad row.
    pub fn error_at(&self, (argument, i): (BadArgument, usize)) -> Error {
        match (argument, self.tmax) {
            (BadArgument::Origins, _) => Error::invalid(
                "origins",
                format!("row {i} is not finite: {:?}", self.origins[i]),
            ),
            (BadArgument::Directions, _) => Error::invalid(
                "directions",
                format!(
                    "row {i} must be finite with a length in [{MIN_DIRECTION_LENGTH:e}, \
                     {MAX_DIRECTION_LENGTH:e}] (t is measured in units of it), got {:?}",
                    self.directions[i]
                ),
            ),
            (BadArgument::Tmax, TMax::PerRay(t)) => {
                Error::invalid("tmax", format!("value {i} must be >= 0, got {}", t[i]))
            }
            (BadArgument::Tmax, TMax::Scalar(t)) => {
                Error::invalid("tmax", format!("must be >= 0, got {t}"))
            }
        }
    }
}

/// The shortest direction a ray may have: its squared length must be a normal `f32`
/// (see `bad_direction`).
pub const MIN_DIRECTION_LENGTH: f32 = 1.0842022e-19;

/// The longest direction a ray may have: its squared length must be finite.
pub const MAX_DIRECTION_LENGTH: f32 = 1.8446743e19;

/// The argument of a [`RayBatch`] that holds a bad row, in the order errors are reported.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum BadArgument {
    Origins,
    Directions,
    Tmax,
}

/// An origin with a non-finite coordinate (branch-free).
#[inline(always)]
fn bad_origin(r: &[f32; 3]) -> bool {
    !(r[0].is_finite() & r[1].is_finite() & r[2].is_finite())
}

/// A direction whose squared length is not a normal `f32` (branch-free): a non-finite
/// coordinate, zero, or a length outside about [1.1e-19, 1.8e19]. `t` is measured in
/// units of the direction's length, so a subnormal direction such as `(0, 0, -1e-40)`
/// would put every hit beyond `f32`'s range (it reported a hit at `t = inf`), and the
/// tracer's normalisations and coherence tests square it. Rays are not renormalised:
/// that would change what `t` means for every caller.
#[inline(always)]
fn bad_direction(r: &[f32; 3]) -> bool {
    let l2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
    !(f32::MIN_POSITIVE..=f32::MAX).contains(&l2)
}

/// A segment end that is NaN or negative.
#[inline(always)]
fn bad_tmax(t: f32) -> bool {
    t.is_nan() | (t < 0.0)
}

/// Index of the first item for which `bad` holds: a branch-free pass, and a search only
/// when it finds one.
#[inline]
fn first_in<T>(items: &[T], bad: impl Fn(&T) -> bool) -> Option<usize> {
    let any = items.iter().fold(false, |acc, x| acc | bad(x));
    if any {
        items.iter().position(bad)
    } else {
        None
    }
}

/// [`first_in`] over fixed chunks scanned in parallel.
fn first_where<T: Sync>(items: &[T], bad: impl Fn(&T) -> bool + Sync) -> Option<usize> {
    const SCAN: usize = 16 * 1024;
    items
        .par_chunks(SCAN)
        .enumerate()
        .find_map_first(|(c, chunk)| first_in(chunk, &bad).map(|i| c * SCAN + i))
}

/// Closest hits of a batch, one entry per ray. Misses have `t = inf`, `prim = obj = -1`,
/// `u = v = 0` and NaN position and normal.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Hits {
    pub t: Vec<f32>,
    pub prim: Vec<i32>,
    pub obj: Vec<i32>,
    pub u: Vec<f32>,
    pub v: Vec<f32>,
    /// Hit point from the barycentrics (lies on the triangle).
    pub position: Vec<[f32; 3]>,
    /// Unit geometric normal, `(v1 - v0) x (v2 - v0)` normalised: not flipped toward the ray.
    pub normal: Vec<[f32; 3]>,
}
