//! The distribution matrix of a shading point's nearest records (survey Fig. 6.6) and
//! the estimator that draws from it (eq. 6.2).
//!
//! ## Columns (eq. 6.4–6.5)
//! Rows 1–3 (F: `L f_s G V`, U: `L f_s G`, B: `L f_s G_max`) are one pmf per record over
//! the `N` lights, kept as running sums (CDFs); row 4 (C) is uniform, `1/N`, and stored
//! nowhere. The balance heuristic over the `R` records of a row, with equal sample counts,
//! reduces to sampling their average pmf `p̄(k) = (1/R) Σ_r p_r(k)`: pick a record
//! uniformly, then a light from its row. A record whose row is all zero (every light
//! occluded for F) cannot be drawn from: it is left out of that row's average, and a row
//! no record can serve draws nothing.
//!
//! ## Rows (eq. 6.6)
//! With `α = (α_F, α_U, α_B, α_C)` in `(0, 1]`, light `k` belongs to the first row `s` (in
//! order F, U, B, C) with `p̄_s(k) > 0` and `p̄_s(k) >= α_i p̄_i(k)` for every later row
//! `i`: eq. 6.6's weight, 1 there and 0 elsewhere. C is last and positive everywhere, so
//! every light has exactly one owner and the weights sum to 1. A draw from row `s` of a
//! light it does not own weighs 0: it is known before the shadow ray, and none is traced.
//! [`Combine::Balance`] (Fig. 6.7a's `p_b`) weighs a draw `p̄_s(k) / Σ_i p̄_i(k)` instead;
//! [`Combine::Only`] draws from one row with weight 1 (biased where that row misses a
//! light: for comparison only).
//!
//! ## Estimator (eq. 6.2)
//! `n` draws per row: `Σ_s (1/n) Σ_j w_s(k_j) f(k_j) / p̄_s(k_j)`, unbiased for `Σ_k f(k)`
//! under [`Combine::AlphaMax`] and [`Combine::Balance`] wherever `f(k) > 0` implies a
//! positive weight somewhere (C guarantees it). Draw `j` of row `s` reads dimensions
//! `2 (s n + j)` and `+ 1` of its sample's stream: a pure function of the stream.

use glam::DVec3;

use crate::error::{Error, Result};
use crate::sampling::rng::{hash4, to_unit_f64};

/// Rows of the distribution matrix, in the α-max heuristic's order.
pub const ROWS: usize = 4;

/// One row of the distribution matrix.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Row {
    /// `L f_s G V`: the record's light with visibility.
    F = 0,
    /// `L f_s G`: without visibility.
    U = 1,
    /// `L f_s G_max`: a bound over the record's region.
    B = 2,
    /// Uniform over the lights.
    C = 3,
}

impl Row {
    /// Every row, in order.
    pub const ALL: [Row; ROWS] = [Row::F, Row::U, Row::B, Row::C];
}

/// How the rows' draws are weighted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Combine {
    /// Eq. 6.6 with confidences `α` for F, U, B, C, each in `(0, 1]`.
    AlphaMax([f64; ROWS]),
    /// The balance heuristic over the rows.
    Balance,
    /// One row alone, weight 1 (biased where it misses a light).
    Only(Row),
}

impl Combine {
    /// The names `combine=` takes, in the order errors list them.
    pub const NAMES: [&'static str; 6] = ["alpha_max", "balance", "F", "U", "B", "C"];

    /// The combination called `name` ([`Self::NAMES`]; `alpha_max` with confidences
    /// `alpha`), validated; an error naming `combine` (or `alpha`) otherwise.
    pub fn parse(name: &str, alpha: [f64; ROWS]) -> Result<Self> {
        let c = match name {
            "alpha_max" => Combine::AlphaMax(alpha),
            "balance" => Combine::Balance,
            "F" => Combine::Only(Row::F),
            "U" => Combine::Only(Row::U),
            "B" => Combine::Only(Row::B),
            "C" => Combine::Only(Row::C),
            _ => {
                return Err(Error::invalid(
                    "combine",
                    format!("expected one of {:?}, got {name:?}", Self::NAMES),
                ))
            }
        };
        c.validate()?;
        Ok(c)
    }

    /// Its name ([`Self::NAMES`]).
    pub fn name(&self) -> &'static str {
        match self {
            Combine::AlphaMax(_) => "alpha_max",
            Combine::Balance => "balance",
            Combine::Only(r) => Self::NAMES[2 + *r as usize],
        }
    }

    /// Fails, naming `alpha`, on confidences outside `(0, 1]`.
    pub fn validate(&self) -> Result<()> {
        if let Combine::AlphaMax(alpha) = self {
            if let Some(a) = alpha.iter().find(|a| !(**a > 0.0 && **a <= 1.0)) {
                return Err(Error::invalid(
                    "alpha",
                    format!("each of (α_F, α_U, α_B, α_C) must lie in (0, 1], got {a}"),
                ));
            }
        }
        Ok(())
    }
}

/// A running sum's entry: `f64`, or `f32` as the importance cache's records store them
/// (at most 12 bytes per light for rows F, U, B). Draws and pmfs read the stored values widened
/// to `f64`, so a light's drawn probability is exactly the pmf evaluated for it.
pub trait CdfValue: Copy + Sync {
    /// The value as `f64` (exact).
    fn get(self) -> f64;
}

impl CdfValue for f64 {
    #[inline(always)]
    fn get(self) -> f64 {
        self
    }
}

impl CdfValue for f32 {
    #[inline(always)]
    fn get(self) -> f64 {
        self as f64
    }
}

/// A record's row as the matrix reads it: running sums over every light (dense), or over
/// the lights of non-zero mass alone, in ascending order (sparse). Both give a light the
/// same mass: a sparse row is the dense one without its repeated sums.
#[derive(Clone, Copy, Debug)]
pub struct CdfView<'a, T: CdfValue = f64> {
    /// The lights of the entries (sparse), or `None` (dense: entry `k` is light `k`).
    lights: Option<&'a [u32]>,
    /// Running sums, non-decreasing, finite.
    cdf: &'a [T],
}

impl<'a, T: CdfValue> CdfView<'a, T> {
    /// A dense row: `cdf[k]` sums lights `0..=k`.
    pub fn dense(cdf: &'a [T]) -> Self {
        Self { lights: None, cdf }
    }

    /// A sparse row: `cdf[i]` sums the lights `lights[..=i]` (ascending, distinct), every
    /// other light of mass 0. Panics when the lengths differ (a programming error).
    pub fn sparse(lights: &'a [u32], cdf: &'a [T]) -> Self {
        assert_eq!(lights.len(), cdf.len(), "a light per entry");
        Self {
            lights: Some(lights),
            cdf,
        }
    }

    /// The row's total (0 when empty).
    #[inline]
    pub fn total(&self) -> f64 {
        self.cdf.last().map_or(0.0, |t| t.get())
    }

    /// Light `k`'s mass.
    #[inline]
    pub fn entry(&self, k: usize) -> f64 {
        let i = match self.lights {
            None => k,
            Some(lights) => match lights.binary_search(&(k as u32)) {
                Ok(i) => i,
                Err(_) => return 0.0,
            },
        };
        self.cdf[i].get() - if i == 0 { 0.0 } else { self.cdf[i - 1].get() }
    }

    /// The first light whose running sum passes `u` in `[0, total)`: never one of zero
    /// mass.
    #[inline]
    fn find(&self, u: f64) -> usize {
        let i = self
            .cdf
            .partition_point(|&x| x.get() <= u)
            .min(self.cdf.len() - 1);
        self.lights.map_or(i, |l| l[i] as usize)
    }
}

/// The distribution matrix at one shading point: for rows F, U, B the CDFs of the records
/// that can serve it, row C implicit.
///
/// Invariants: every row is over `lights` lights (dense rows have `lights` entries,
/// sparse ones name lights below it), its total `> 0` and finite.
#[derive(Clone, Debug, Default)]
pub struct Matrix<'a, T: CdfValue = f64> {
    lights: usize,
    rows: [Vec<CdfView<'a, T>>; ROWS - 1],
}

impl<'a, T: CdfValue> Matrix<'a, T> {
    /// An empty matrix over `lights` lights (row C alone); an error naming `lights` for
    /// none.
    pub fn new(lights: usize) -> Result<Self> {
        if lights == 0 {
            return Err(Error::invalid("lights", "the light set is empty"));
        }
        Ok(Self {
            lights,
            rows: Default::default(),
        })
    }

    /// Number of lights.
    pub fn lights(&self) -> usize {
        self.lights
    }

    /// Adds a record's CDF of row `row` (F, U or B): left out, as eq. 6.5's average allows,
    /// when its total is not positive and finite (nothing to draw). Panics on a CDF of
    /// another length or on row C (programming errors).
    pub fn push(&mut self, row: Row, cdf: &'a [T]) {
        assert_eq!(cdf.len(), self.lights, "a CDF per light");
        self.push_view(row, CdfView::dense(cdf));
    }

    /// [`Self::push`] for a row of either form. Panics on row C or a sparse row naming a
    /// light beyond the set (programming errors).
    pub fn push_view(&mut self, row: Row, view: CdfView<'a, T>) {
        assert!(row != Row::C, "row C is uniform and stored nowhere");
        match view.lights {
            None => assert_eq!(view.cdf.len(), self.lights, "a CDF per light"),
            Some(l) => assert!(l.last().is_none_or(|&k| (k as usize) < self.lights)),
        }
        let total = view.total();
        if total > 0.0 && total.is_finite() {
            self.rows[row as usize].push(view);
        }
    }

    /// Records serving `row` (C: 1, itself).
    pub fn records(&self, row: Row) -> usize {
        match row {
            Row::C => 1,
            r => self.rows[r as usize].len(),
        }
    }

    /// `p̄_row(k)`, eq. 6.5's average of the records' pmfs (0 when no record serves it).
    pub fn pmf(&self, row: Row, k: usize) -> f64 {
        if row == Row::C {
            return 1.0 / self.lights as f64;
        }
        let cdfs = &self.rows[row as usize];
        if cdfs.is_empty() {
            return 0.0;
        }
        let sum: f64 = cdfs.iter().map(|c| c.entry(k) / c.total()).sum();
        sum / cdfs.len() as f64
    }

    /// A light drawn from `p̄_row` with uniforms `u_record`, `u_light` in `[0, 1)`: a record
    /// uniformly, then a light from its row; `None` when no record serves the row.
    pub fn draw(&self, row: Row, u_record: f64, u_light: f64) -> Option<usize> {
        let n = self.lights;
        if row == Row::C {
            return Some(((u_light * n as f64) as usize).min(n - 1));
        }
        let cdfs = &self.rows[row as usize];
        if cdfs.is_empty() {
            return None;
        }
        let c = cdfs[((u_record * cdfs.len() as f64) as usize).min(cdfs.len() - 1)];
        Some(c.find(u_light * c.total()).min(n - 1))
    }

    /// The weight of a draw of light `k` from row `s` under `combine` (module docs).
    pub fn weight(&self, combine: &Combine, s: Row, k: usize) -> f64 {
        let p = Row::ALL.map(|r| self.pmf(r, k));
        weight_of(combine, s, &p)
    }

    /// Eq. 6.2 over `draws` draws per row: `Σ_s (1/n) Σ_j w f(k_j) / p̄_s(k_j)`, the draws
    /// from the stream `(seed, stream, sample)` (module docs). `f(k)` (the light's
    /// contribution, shadow ray included) is called only for draws of positive weight.
    /// Also the number of calls of `f`.
    pub fn estimate(
        &self,
        combine: &Combine,
        draws: u32,
        (seed, stream, sample): (u64, u64, u64),
        mut f: impl FnMut(usize) -> DVec3,
    ) -> (DVec3, u32) {
        let (mut sum, mut calls) = (DVec3::ZERO, 0);
        let n = draws.max(1) as f64;
        for s in Row::ALL {
            if matches!(combine, Combine::Only(only) if *only != s) {
                continue;
            }
            for j in 0..draws as u64 {
                let d = 2 * (s as u64 * draws as u64 + j);
                let u = |d| to_unit_f64(hash4(seed, stream, sample, d));
                let Some(k) = self.draw(s, u(d), u(d + 1)) else {
                    break;
                };
                let p = Row::ALL.map(|r| self.pmf(r, k));
                let w = weight_of(combine, s, &p);
                if w > 0.0 && p[s as usize] > 0.0 {
                    calls += 1;
                    sum += f(k) * (w / (n * p[s as usize]));
                }
            }
        }
        (sum, calls)
    }
}

/// The weight of a draw from row `s` of a light whose rows' pmfs are `p` (module docs).
fn weight_of(combine: &Combine, s: Row, p: &[f64; ROWS]) -> f64 {
    let s = s as usize;
    match combine {
        Combine::Only(only) => (*only as usize == s) as u8 as f64,
        Combine::Balance => {
            let total: f64 = p.iter().sum();
            if total > 0.0 {
                p[s] / total
            } else {
                0.0
            }
        }
        Combine::AlphaMax(alpha) => {
            let owner =
                (0..ROWS).find(|&r| p[r] > 0.0 && (r + 1..ROWS).all(|i| p[r] >= alpha[i] * p[i]));
            (owner == Some(s)) as u8 as f64
        }
    }
}

#[cfg(test)]
mod tests;
