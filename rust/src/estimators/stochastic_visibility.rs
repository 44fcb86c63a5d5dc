//! Probabilistic visibility with geometry proxies (BLD, `002_f6f7ae5fac667f5c.txt`): a
//! shadow ray tests a cheap proxy set `P'` instead of the scene `P`, or a correction term
//! that needs both, chosen at random, and the estimate of `V_P` stays unbiased.
//!
//! ## The estimator (eq. 4–8)
//! `V_P = V_P' + V_P (1 − V_P') − V_P' (1 − V_P)` (eq. 5): the proxy's answer, plus the
//! rays it over-occludes (type 3 of Table 1: miss `P`, hit `P'`), minus those it
//! under-occludes (type 2: hit `P`, miss `P'`). One term, drawn with probability `p_i`
//! and divided by it, is unbiased for the sum (eq. 7–8):
//!
//! | term ([`Term`]) | value | traces |
//! |---|---|---|
//! | (a) [`Term::Proxy`] | `V_P' / p1` | `P'` |
//! | (b) [`Term::Over`] | `(1 − V_P') V_P / p2` | `P'`, then `P` only where `V_P' = 0` |
//! | (c) [`Term::Under`] | `−V_P' (1 − V_P) / p3` | `P'`, then `P` only where `V_P' = 1` |
//!
//! Values are `0`, `1/p` or `−1/p`: they flow into the pixel unclamped (clamping to
//! `[0, 1]` would bias it).
//!
//! ## Variance (eq. 9–16) and the probabilities that minimise it (§4.1)
//! With `f_1..f_4` the shares of the four ray types over a point's shadow rays (Table 1),
//! `V_avg = f_3 + f_4`, `f_hit = f_1 / (f_1 + f_2)`, `f_miss = f_4 / (f_3 + f_4)`, and
//!
//! `Var = (f_2 + f_4) / p1 + f_3 / p2 + f_2 / p3 − V_avg²` (eq. 14),
//!
//! i.e. `Σ a_i / p_i − V_avg²` with `a = (f_2 + f_4, f_3, f_2)`. Over `p1 + p2 + p3 = 1`
//! it is least at `p_i = √a_i / Σ_j √a_j` (Lagrange: `a_i / p_i² ` equal for every `i`),
//! where it is `(Σ √a_i)² − V_avg²`. The paper gives this for outside proxies (`f_2 = 0`,
//! eq. 18: `p1 = √f_miss / (√f_miss + √(1 − f_miss))`, its `(f_miss − √(f_miss −
//! f_miss²)) / (2 f_miss − 1)` without the `0/0` at `f_miss = 1/2`) and for inside
//! proxies (`f_3 = 0`, eq. 20), but tabulates general proxies numerically: the same
//! closed form serves them, so no table is needed ([`Probabilities::least_variance`];
//! the tests check it against a brute-force search of the simplex).
//!
//! ## Cost (§4.2, eq. 22–24)
//! Every term traces the proxy; (b) traces the scene on the rays the proxy blocks
//! (`f_1 + f_3`), (c) on those it lets through (`f_2 + f_4`). With `c'` and `c` the
//! costs of a proxy and a scene test, a shadow ray costs `c' + c (p2 (f_1 + f_3) + p3
//! (f_2 + f_4))`. The paper found no closed form for the probabilities that minimise
//! variance × cost and scales `p2`, `p3` by `(1 − (f_1 + f_4))^{1/4}` instead
//! ([`Probabilities::cost_heuristic`]); [`Probabilities::least_work`] minimises the
//! product itself, numerically.

use crate::error::{Error, Result};

pub use crate::geometry::proxies::ProxyKind;

/// One of eq. 8's terms.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Term {
    /// (a) `V_P' / p1`: the proxy alone.
    Proxy,
    /// (b) `(1 − V_P') V_P / p2`: adds back what the proxy over-occludes.
    Over,
    /// (c) `−V_P' (1 − V_P) / p3`: takes off what it under-occludes.
    Under,
}

impl Term {
    /// Whether this term can be non-zero for a ray under proxies of `kind`: outside proxies
    /// never under-occlude (eq. 17–18), inside ones never over-occlude (eq. 19–20).
    pub const fn needed_under(self, kind: ProxyKind) -> bool {
        !matches!(
            (kind, self),
            (ProxyKind::Outside, Term::Under) | (ProxyKind::Inside, Term::Over)
        )
    }
}

/// Shares of the four ray types of Table 1 over a point's shadow rays (eq. 9–11).
///
/// Invariant: each share finite and in `[0, 1]`, summing to 1 (within rounding).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fractions {
    /// `f_1`..`f_4`: hit both; hit `P`, miss `P'`; miss `P`, hit `P'`; miss both.
    pub f: [f64; 4],
}

impl Fractions {
    /// The shares given by eq. 9–11's summary figures: `v_avg` (the share of rays `P`
    /// lets through), `f_hit` (of the rays `P` blocks, the share `P'` blocks too) and
    /// `f_miss` (of the rays `P` lets through, the share `P'` lets through too); each in
    /// `[0, 1]`, else an error naming it.
    pub fn new(v_avg: f64, f_hit: f64, f_miss: f64) -> Result<Self> {
        for (name, v) in [("v_avg", v_avg), ("f_hit", f_hit), ("f_miss", f_miss)] {
            if !(0.0..=1.0).contains(&v) {
                return Err(Error::invalid(name, format!("must lie in [0, 1], got {v}")));
            }
        }
        let blocked = 1.0 - v_avg;
        Ok(Self {
            f: [
                blocked * f_hit,
                blocked * (1.0 - f_hit),
                v_avg * (1.0 - f_miss),
                v_avg * f_miss,
            ],
        })
    }

    /// The shares counted on probe rays (`counts[i]` rays of type `i + 1`), each count
    /// plus `prior` (a Beta prior per type, e.g. 0.5: a few probes that saw no type-2
    /// ray do not make its share 0, which would let the least-variance probabilities drop
    /// a term the point needs). `None` without any ray or prior.
    pub fn from_counts(counts: [u64; 4], prior: f64) -> Option<Self> {
        let prior = if prior.is_finite() {
            prior.max(0.0)
        } else {
            0.0
        };
        let n: f64 = counts.iter().map(|&c| c as f64 + prior).sum();
        if n <= 0.0 {
            return None;
        }
        Some(Self {
            f: counts.map(|c| (c as f64 + prior) / n),
        })
    }

    /// `V_avg = f_3 + f_4` (eq. 9).
    pub fn v_avg(&self) -> f64 {
        self.f[2] + self.f[3]
    }

    /// `f_hit` (eq. 10); 1 when no ray is blocked (nothing to get wrong).
    pub fn f_hit(&self) -> f64 {
        let hit = self.f[0] + self.f[1];
        if hit > 0.0 {
            self.f[0] / hit
        } else {
            1.0
        }
    }

    /// `f_miss` (eq. 11); 1 when every ray is blocked.
    pub fn f_miss(&self) -> f64 {
        let miss = self.f[2] + self.f[3];
        if miss > 0.0 {
            self.f[3] / miss
        } else {
            1.0
        }
    }

    /// The weights `a` of `Var = Σ a_i / p_i − V_avg²` (module docs), for
    /// [`Term::Proxy`], [`Term::Over`], [`Term::Under`].
    pub fn variance_weights(&self) -> [f64; 3] {
        [self.f[1] + self.f[3], self.f[2], self.f[1]]
    }
}

/// The probabilities `(p1, p2, p3)` of eq. 8's terms (a), (b), (c).
///
/// Invariant: each finite and in `[0, 1]`, summing to 1 within `1e-9`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Probabilities {
    pub p: [f64; 3],
}

/// How far the probabilities may sum from 1.
const SUM_TOLERANCE: f64 = 1e-9;

impl Probabilities {
    /// `(p1, p2, p3)`, checked: each finite and `>= 0`, summing to 1; an error naming
    /// `probabilities` otherwise.
    pub fn new(p1: f64, p2: f64, p3: f64) -> Result<Self> {
        let p = [p1, p2, p3];
        if let Some(bad) = p.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
            return Err(Error::invalid(
                "probabilities",
                format!("each of (p1, p2, p3) must be finite and >= 0, got {bad}"),
            ));
        }
        let sum: f64 = p.iter().sum();
        if (sum - 1.0).abs() > SUM_TOLERANCE {
            return Err(Error::invalid(
                "probabilities",
                format!("(p1, p2, p3) must sum to 1, got {p1} + {p2} + {p3} = {sum}"),
            ));
        }
        Ok(Self { p })
    }

    /// Equal probabilities over the terms `kind` needs (Fig. 5's "equal" columns):
    /// `(1/2, 1/2, 0)` outside, `(1/2, 0, 1/2)` inside, `1/3` each in general.
    pub fn equal(kind: ProxyKind) -> Self {
        let needed = Term::ALL.map(|t| t.needed_under(kind) as u8 as f64);
        let n: f64 = needed.iter().sum();
        Self {
            p: needed.map(|x| x / n),
        }
    }

    /// The probability of term `t`.
    pub fn of(&self, t: Term) -> f64 {
        self.p[t as usize]
    }

    /// Fails, naming `probabilities`, where a term `kind` needs has probability 0: its
    /// rays would count for nothing, and the estimate would be biased.
    pub fn check_unbiased(&self, kind: ProxyKind) -> Result<()> {
        match Term::ALL
            .into_iter()
            .find(|&t| t.needed_under(kind) && self.of(t) <= 0.0)
        {
            Some(t) => Err(Error::invalid(
                "probabilities",
                format!(
                    "term {t:?} has probability 0, but {} proxies need it (the estimate \
                     would be biased)",
                    kind.name()
                ),
            )),
            None => Ok(()),
        }
    }

    /// The term that uniform `u` in `[0, 1)` draws: (a) below `p1`, (b) below `p1 + p2`,
    /// else (c) — never a term of probability 0.
    pub fn choose(&self, u: f64) -> Term {
        let (mut acc, mut last) = (0.0, Term::Proxy);
        for t in Term::ALL {
            let p = self.of(t);
            if p <= 0.0 {
                continue;
            }
            (acc, last) = (acc + p, t);
            if u < acc {
                return t;
            }
        }
        last
    }

    /// Eq. 14: the variance of one ray's estimate over a point's rays with shares `fr`
    /// (`+∞` where a needed term has probability 0).
    pub fn variance(&self, fr: &Fractions) -> f64 {
        let mut second = 0.0;
        for (a, p) in fr.variance_weights().into_iter().zip(self.p) {
            if a > 0.0 {
                second += a / p;
            }
        }
        second - fr.v_avg() * fr.v_avg()
    }

    /// The probabilities of least variance for shares `fr` (module docs: `p_i ∝ √a_i`),
    /// each then at least `floor` where `kind` needs its term (and renormalised), so that
    /// shares estimated from a few probes never drop a term a point needs. `floor` in
    /// `[0, 1/3]`.
    pub fn least_variance(fr: &Fractions, kind: ProxyKind, floor: f64) -> Self {
        let roots = fr.variance_weights().map(f64::sqrt);
        let sum: f64 = roots.iter().sum();
        let p = if sum > 0.0 {
            roots.map(|r| r / sum)
        } else {
            // Every ray is of type 1: V = 0 whatever is traced; the proxy alone is cheapest.
            [1.0, 0.0, 0.0]
        };
        Self { p }.floored(kind, floor)
    }

    /// Eq. 22–24: `p2`, `p3` scaled by `(1 − (f_1 + f_4))^{1/4}` and `p1` taking the rest
    /// (then `floor` as in [`Self::least_variance`]).
    pub fn cost_heuristic(&self, fr: &Fractions, kind: ProxyKind, floor: f64) -> Self {
        let agree = (fr.f[0] + fr.f[3]).clamp(0.0, 1.0);
        let s = (1.0 - agree).powf(0.25);
        let (p2, p3) = (self.p[1] * s, self.p[2] * s);
        Self {
            p: [1.0 - p2 - p3, p2, p3],
        }
        .floored(kind, floor)
    }

    /// Expected cost of one ray (module docs), with `proxy_cost` and `scene_cost` the
    /// costs of a test against `P'` and `P` (any unit, `>= 0`).
    pub fn cost(&self, fr: &Fractions, proxy_cost: f64, scene_cost: f64) -> f64 {
        let blocked_by_proxy = fr.f[0] + fr.f[2];
        proxy_cost
            + scene_cost * (self.p[1] * blocked_by_proxy + self.p[2] * (1.0 - blocked_by_proxy))
    }

    /// The probabilities that minimise variance × cost ([`Self::variance`] ×
    /// [`Self::cost`]) over those with every term `kind` needs at `floor` or more, by a
    /// grid search of the simplex refined three times about its best point (to about
    /// `1e-4` in each probability). Falls back to [`Self::least_variance`] where the
    /// variance is 0 (the product is then 0 everywhere).
    pub fn least_work(
        fr: &Fractions,
        kind: ProxyKind,
        floor: f64,
        proxy_cost: f64,
        scene_cost: f64,
    ) -> Self {
        let start = Self::least_variance(fr, kind, floor);
        let work = |p: &Self| {
            let v = p.variance(fr).max(0.0);
            v * p.cost(fr, proxy_cost, scene_cost)
        };
        if work(&start) <= 0.0 {
            return start;
        }
        let (mut best, mut best_work) = (start, work(&start));
        let (mut centre, mut half) = ([1.0 / 3.0; 2], 0.5f64);
        const STEPS: i32 = 24;
        for _ in 0..4 {
            for i in -STEPS..=STEPS {
                for j in -STEPS..=STEPS {
                    let p2 = centre[0] + half * i as f64 / STEPS as f64;
                    let p3 = centre[1] + half * j as f64 / STEPS as f64;
                    let p1 = 1.0 - p2 - p3;
                    if p1 < 0.0 || p2 < 0.0 || p3 < 0.0 {
                        continue;
                    }
                    let candidate = Self { p: [p1, p2, p3] };
                    if !candidate.meets_floor(kind, floor) {
                        continue;
                    }
                    let w = work(&candidate);
                    if w < best_work {
                        (best, best_work) = (candidate, w);
                    }
                }
            }
            centre = [best.p[1], best.p[2]];
            half *= 4.0 / STEPS as f64;
        }
        best
    }

    /// Whether every term `kind` needs has probability `>= floor` and the others 0.
    fn meets_floor(&self, kind: ProxyKind, floor: f64) -> bool {
        Term::ALL.into_iter().all(|t| {
            if t.needed_under(kind) {
                self.of(t) >= floor - 1e-12
            } else {
                self.of(t) == 0.0
            }
        })
    }

    /// Terms `kind` cannot use set to 0, the others raised to at least `floor` (taken
    /// from those above it, in proportion to their excess), summing to 1.
    fn floored(self, kind: ProxyKind, floor: f64) -> Self {
        let floor = floor.clamp(0.0, 1.0 / 3.0);
        let mut p = self.p;
        for t in Term::ALL {
            if !t.needed_under(kind) {
                p[t as usize] = 0.0;
            }
        }
        let sum: f64 = p.iter().sum();
        if sum <= 0.0 {
            return Self::equal(kind);
        }
        p = p.map(|x| x / sum);
        let needed: Vec<usize> = Term::ALL
            .into_iter()
            .filter(|&t| t.needed_under(kind))
            .map(|t| t as usize)
            .collect();
        let short: f64 = needed.iter().map(|&i| (floor - p[i]).max(0.0)).sum();
        if short > 0.0 {
            let excess: f64 = needed.iter().map(|&i| (p[i] - floor).max(0.0)).sum();
            for &i in &needed {
                p[i] = if p[i] <= floor {
                    floor
                } else {
                    p[i] - short * (p[i] - floor) / excess
                };
            }
        }
        // The last needed term takes the rounding.
        let last = *needed.last().expect("every kind needs the proxy term");
        p[last] = 1.0
            - needed
                .iter()
                .filter(|&&i| i != last)
                .map(|&i| p[i])
                .sum::<f64>();
        Self { p }
    }
}

impl Term {
    /// Every term, in eq. 8's order.
    pub const ALL: [Term; 3] = [Term::Proxy, Term::Over, Term::Under];
}

/// One draw of eq. 8 for a ray: the term that `u` (in `[0, 1)`) picks, the proxy's answer
/// `proxy_visible` and, called only where the term needs it, the scene's. Returns the
/// estimate (`0`, `1/p` or `−1/p`, unclamped) and whether the scene was traced.
pub fn estimate(
    p: &Probabilities,
    u: f64,
    proxy_visible: bool,
    scene_visible: impl FnOnce() -> bool,
) -> (f64, bool) {
    let t = p.choose(u);
    let pt = p.of(t);
    match t {
        Term::Proxy => ((proxy_visible as u8 as f64) / pt, false),
        // (1 − V_P') V_P: zero where the proxy lets the ray through.
        Term::Over if proxy_visible => (0.0, false),
        Term::Over => ((scene_visible() as u8 as f64) / pt, true),
        // −V_P' (1 − V_P): zero where the proxy blocks the ray.
        Term::Under if !proxy_visible => (0.0, false),
        Term::Under => (-((!scene_visible()) as u8 as f64) / pt, true),
    }
}

pub mod split;

#[cfg(test)]
mod tests;
