//! Pearson's chi-square goodness-of-fit test of a direction sampler against its pdf, as a
//! library feature (after Mitsuba 3's `mi.chi2` and pbrt-v4's sampler tests).
//!
//! The sphere is cut into the `res x res` texels of the equal-area octahedral map, so every
//! bin has the same solid angle and the expected count of a bin is the pdf integrated over
//! it by a midpoint rule on a `subdivisions²` sub-grid (area-uniform, because the map is).
//! When a sampler rejects samples (`None`), they form one more bin whose expected count is
//! the pdf's missing mass, so a pdf that does not integrate to the acceptance rate fails.
//! Bins with small expected counts are pooled; a sample where the pdf is zero fails the
//! test outright.

use glam::{UVec2, Vec2, Vec3};
use rayon::prelude::*;

use super::octahedral::{square_to_sphere, texel_of, texel_solid_angle};

/// Parameters of [`chi2_sphere`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chi2Params {
    /// Side of the octahedral grid of bins (`res²` bins of equal solid angle).
    pub resolution: u32,
    /// Midpoint sub-grid per bin and axis used to integrate the pdf.
    pub subdivisions: u32,
    /// Bins whose expected count is below this are pooled (5 is Pearson's rule of thumb).
    pub min_expected: f64,
    /// The test passes when the p-value is at least this.
    pub significance: f64,
}

impl Chi2Params {
    /// 32² bins, 8² integration points per bin, pooling below 5, α = 0.01.
    pub const DEFAULT: Self = Self {
        resolution: 32,
        subdivisions: 8,
        min_expected: 5.0,
        significance: 0.01,
    };

    /// The default with another bin grid.
    pub const fn with_resolution(resolution: u32) -> Self {
        Self {
            resolution,
            ..Self::DEFAULT
        }
    }

    /// The same parameters with another integration sub-grid.
    pub const fn with_subdivisions(self, subdivisions: u32) -> Self {
        Self {
            subdivisions,
            ..self
        }
    }
}

impl Default for Chi2Params {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Outcome of [`chi2_sphere`].
#[derive(Clone, Debug, PartialEq)]
pub struct Chi2Outcome {
    /// Pearson's statistic over the bins that were used.
    pub statistic: f64,
    /// Degrees of freedom: bins used minus one.
    pub dof: usize,
    /// Probability of a statistic at least this large if the sampler matched its pdf.
    pub p_value: f64,
    /// Integral of the pdf over the sphere (midpoint rule); 1 for a normalised pdf.
    pub integral: f64,
    /// Samples in directions where the pdf itself is zero (or NaN).
    pub samples_where_pdf_is_zero: u64,
    /// Samples the sampler rejected.
    pub rejected: u64,
    /// Whether `p_value >= significance` and no sample landed where the pdf is zero.
    pub passed: bool,
}

/// Survival function of the chi-square distribution with `dof` degrees of freedom:
/// `P(X >= statistic)`, the regularised upper incomplete gamma `Q(dof/2, statistic/2)`.
pub fn chi2_survival(statistic: f64, dof: f64) -> f64 {
    if statistic <= 0.0 {
        return 1.0;
    }
    statrs::function::gamma::gamma_ur(dof / 2.0, statistic / 2.0)
}

/// The midpoint-rule points of every bin, bin after bin in row-major order (`y * res + x`),
/// `subdivisions²` per bin: evaluate a pdf here and sum per bin (times
/// [`integration_weight`]) to get what [`chi2_binned`] takes.
pub fn integration_directions(params: &Chi2Params) -> Vec<Vec3> {
    let res = params.resolution;
    let sub = params.subdivisions.max(1);
    let mut dirs = Vec::with_capacity((res * res * sub * sub) as usize);
    for i in 0..res * res {
        let texel = UVec2::new(i % res, i / res);
        for sy in 0..sub {
            for sx in 0..sub {
                let within = (Vec2::new(sx as f32, sy as f32) + 0.5) / sub as f32;
                dirs.push(square_to_sphere((texel.as_vec2() + within) / res as f32));
            }
        }
    }
    dirs
}

/// Solid angle each integration point stands for.
pub fn integration_weight(params: &Chi2Params) -> f64 {
    let sub = params.subdivisions.max(1) as f64;
    texel_solid_angle(params.resolution) / (sub * sub)
}

/// Per-bin integrals of `pdf` over the `res x res` octahedral texels, in row-major order
/// (`y * res + x`).
pub fn integrate_bins(pdf: &(impl Fn(Vec3) -> f64 + Sync), params: &Chi2Params) -> Vec<f64> {
    let per_bin = (params.subdivisions.max(1) as usize).pow(2);
    let weight = integration_weight(params);
    integration_directions(params)
        .par_chunks(per_bin)
        .map(|points| points.iter().map(|&d| pdf(d)).sum::<f64>() * weight)
        .collect()
}

/// Tests `samples` (one entry per attempt; `None` when the sampler rejected it) against the
/// solid-angle `pdf` they should follow.
pub fn chi2_sphere(
    samples: impl IntoIterator<Item = Option<Vec3>>,
    pdf: impl Fn(Vec3) -> f64 + Sync,
    params: &Chi2Params,
) -> Chi2Outcome {
    let samples: Vec<Option<Vec3>> = samples.into_iter().collect();
    let impossible = samples
        .iter()
        .flatten()
        .filter(|&&d| pdf(d).partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater))
        .count() as u64;
    chi2_binned(&samples, impossible, integrate_bins(&pdf, params), params)
}

/// The test of [`chi2_sphere`] from its parts: the samples, how many of them lie where the
/// pdf is zero, and the pdf's integral over every bin (row-major, `res²` entries).
pub fn chi2_binned(
    samples: &[Option<Vec3>],
    samples_where_pdf_is_zero: u64,
    mut integrals: Vec<f64>,
    params: &Chi2Params,
) -> Chi2Outcome {
    let res = params.resolution;
    let mut observed = vec![0u64; (res * res) as usize + 1];
    for s in samples {
        let bin = match s {
            Some(d) => {
                let t = texel_of(*d, res);
                (t.y * res + t.x) as usize
            }
            None => (res * res) as usize,
        };
        observed[bin] += 1;
    }
    let n = samples.len() as f64;
    let integral: f64 = integrals.iter().sum();
    let rejected = observed[(res * res) as usize];
    if rejected > 0 {
        integrals.push((1.0 - integral).max(0.0));
    } else {
        // Without rejections the missing mass would only measure the quadrature's error at
        // the pdf's discontinuities; a pdf of the wrong total still fails in every bin.
        observed.pop();
    }
    let expected: Vec<f64> = integrals.iter().map(|p| p * n).collect();
    let mut outcome = pearson(&observed, &expected, params, integral, rejected);
    outcome.samples_where_pdf_is_zero = samples_where_pdf_is_zero;
    outcome.passed &= samples_where_pdf_is_zero == 0;
    outcome
}

/// Pearson's test of `observed` against `expected` counts with pooling of small bins.
fn pearson(
    observed: &[u64],
    expected: &[f64],
    params: &Chi2Params,
    integral: f64,
    rejected: u64,
) -> Chi2Outcome {
    let mut order: Vec<usize> = (0..observed.len()).collect();
    order.sort_by(|&a, &b| expected[a].total_cmp(&expected[b]));
    let (mut pool_obs, mut pool_exp) = (0.0, 0.0);
    let mut bins: Vec<(f64, f64)> = Vec::new();
    for &i in &order {
        let (o, e) = (observed[i] as f64, expected[i]);
        // A bin the quadrature found empty may still hold a sliver of support; it is pooled
        // (samples whose own pdf is zero are caught by the caller).
        if e < params.min_expected {
            pool_obs += o;
            pool_exp += e;
        } else {
            bins.push((o, e));
        }
    }
    if pool_exp >= params.min_expected || (bins.is_empty() && pool_exp > 0.0) {
        bins.push((pool_obs, pool_exp));
    } else if let Some(smallest) = bins.first_mut() {
        // Too little to stand alone: fold the pool into the smallest regular bin.
        smallest.0 += pool_obs;
        smallest.1 += pool_exp;
    }
    let statistic: f64 = bins.iter().map(|(o, e)| (o - e) * (o - e) / e).sum();
    let dof = bins.len().saturating_sub(1);
    let p_value = chi2_survival(statistic, dof.max(1) as f64);
    Chi2Outcome {
        statistic,
        dof,
        p_value,
        integral,
        samples_where_pdf_is_zero: 0,
        rejected,
        passed: p_value >= params.significance,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::{hash4, to_unit_f32};

    fn uniform_sphere(i: u64) -> Vec3 {
        let u = to_unit_f32(hash4(11, i, 0, 0));
        let v = to_unit_f32(hash4(11, i, 0, 1));
        square_to_sphere(Vec2::new(u, v))
    }

    #[test]
    fn survival_function_known_values() {
        // P(X >= 3.841) = 0.05 for one degree of freedom; P(X >= 2 ln 2 ...) for two: e^{-x/2}.
        assert!((chi2_survival(3.841_458_8, 1.0) - 0.05).abs() < 1e-6);
        assert!((chi2_survival(4.0, 2.0) - (-2.0f64).exp()).abs() < 1e-12);
        assert_eq!(chi2_survival(0.0, 5.0), 1.0);
    }

    #[test]
    fn accepts_a_correct_sampler_and_rejects_wrong_ones() {
        let uniform_pdf = |_: Vec3| 1.0 / (4.0 * std::f64::consts::PI);
        let params = Chi2Params::with_resolution(16);
        let ok = chi2_sphere(
            (0..200_000).map(|i| Some(uniform_sphere(i))),
            uniform_pdf,
            &params,
        );
        assert!(ok.passed, "{ok:?}");
        assert!((ok.integral - 1.0).abs() < 1e-6);

        // Upper hemisphere samples against a full-sphere pdf: half the sphere gets none.
        let upper = |i| {
            let d = uniform_sphere(i);
            Some(Vec3::new(d.x, d.y.abs(), d.z))
        };
        let bad = chi2_sphere((0..200_000).map(upper), uniform_pdf, &params);
        assert!(!bad.passed && bad.p_value < 1e-12, "{bad:?}");

        // A pdf that is zero where samples land.
        let half_pdf = |d: Vec3| {
            if d.y > 0.0 {
                0.5 / std::f64::consts::PI
            } else {
                0.0
            }
        };
        let zero = chi2_sphere(
            (0..10_000).map(|i| Some(uniform_sphere(i))),
            half_pdf,
            &params,
        );
        assert!(
            !zero.passed && zero.samples_where_pdf_is_zero > 0,
            "{zero:?}"
        );

        // A sampler that rejects half its attempts matches a pdf of mass 1/2.
        // (The cut is x = 0, a bin boundary, so the midpoint rule integrates it exactly.)
        let half_mass = |d: Vec3| {
            if d.x > 0.0 {
                0.25 / std::f64::consts::PI
            } else {
                0.0
            }
        };
        let rejecting = (0..200_000).map(|i| {
            let d = uniform_sphere(i);
            (d.x > 0.0).then_some(d)
        });
        let ok = chi2_sphere(rejecting, half_mass, &params);
        assert!(ok.passed && ok.rejected > 0, "{ok:?}");
        // ... but not a pdf that claims all the mass.
        let rejecting = (0..200_000).map(|i| {
            let d = uniform_sphere(i);
            (d.x > 0.0).then_some(d)
        });
        let half_pdf_x = |d: Vec3| {
            if d.x > 0.0 {
                0.5 / std::f64::consts::PI
            } else {
                0.0
            }
        };
        let bad = chi2_sphere(rejecting, half_pdf_x, &params);
        assert!(!bad.passed, "{bad:?}");
    }
}
