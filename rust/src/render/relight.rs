//! The relighter's passes on the pass layer: SBF's relighting with decoupled visibility
//! (Schwenk, Behr & Fellner; its maths in [`crate::estimators::decoupled`]) as a
//! [`PixelEstimator`] that [`run_passes`] drives, and [`relight`], its entry point.
//!
//! ## A pixel's samples
//! A pixel's sample count is its `LBV`-samples per light (one shadow ray each, eq. 9's
//! unbiased part). Its first visit also sets what it sees and each light's `⟨V⟩` and takes
//! its [`RelightParams::lb_spp`] `LB`-samples (no ray), work done once and counted as
//! none of its samples: the pixel is due ([`PixelSums::due`]) until visited, so a pass
//! visits it even at its target (with [`RelightParams::lbv_spp`] 0, a pass of no
//! sample). Every `LBV`-sample's `LB` value is an `LB`-sample too. The first visit's time
//! counts as the pixel's set-up in the pass schedule's model.
//!
//! ## Passes
//! Without a time budget the render is one pass: every pixel visited and given `lbv_spp`
//! `LBV`-samples (SBF's first frame). With one (and `lbv_spp > 0`; without `LBV`-samples
//! there is no unbiased part to add to, and the render is the one pass), that first pass
//! still gives every pixel its `lbv_spp` (the driver's `first_spp`), and the driver's
//! passes that follow bring every pixel to the most `LBV`-samples the first pass's timing
//! says fit the budget left (SBF's later frames, where `Var(LB/p)` is known and a sample
//! costs what a classical one does).
//! With [`RelightParams::adaptive`] (budgets only) the main pass is a pilot of a quarter
//! of its samples, after which each pixel takes a share of the rest ([`SampleShares`],
//! Neyman's allocation) in proportion to `√(v_i / c_i)`, `v_i` the relative variance per
//! `LBV`-sample of its blend, `Σ_l (1 − t_l)² Var(LBV_l/p)` over `μ² + 10⁻²` (what relMSE
//! weighs), and `c_i` its cost per sample, both pooled over its neighbours: pixels whose
//! blend leans on `⟨LB⟩⟨V⟩` take few; those whose `t` fell (penumbrae, a bias measured)
//! take many (SBF §4.1's "number of samples ... proportional to the blending factor", in
//! the measure relMSE sets). Pixels without a surface take none.
//!
//! ## Determinism, progress, stopping
//! Each pixel's samples accumulate in sample order and every random number is a function
//! of `(seed, pixel, stream, sample, dimension)`, so the result is bit-identical for any
//! thread count (under a budget, for the same passes); without adaptive counts it equals
//! a run without a budget asked for the `LBV`-samples taken. Progress is reported in
//! pixel `LBV`-samples; a `false` from it stops the render with [`Error::Interrupted`].

use std::ops::Range;
use std::time::Instant;

use rayon::prelude::*;

use super::adaptive::SampleShares;
use super::estimator::{Merge, PassPlan, PixelEstimator, PixelPass, PixelTiming};
use super::passes::{run_passes, PassParams};
use super::sums::PixelSums;
use crate::bsdf::Material;
use crate::error::{Error, Result};
use crate::estimators::decoupled::{
    GatherWork, RelightParams, RelightPass, RelightSums, Relighter, Relit, MAX_RELIGHT_SPP,
};
use crate::geometry::Scene;
use crate::lights::envmap::EnvMap;
use crate::math::RELMSE_FLOOR;
use crate::visibility::cache::VisibilityCache;

impl PixelSums for RelightSums {
    fn samples(&self) -> u32 {
        self.lbv_samples()
    }

    /// Until its first visit, and below its target.
    fn due(&self, target: u32) -> bool {
        !self.visited() || self.lbv_samples() < target
    }
}

impl Merge for GatherWork {
    fn merge(&mut self, other: Self) {
        self.shadow_rays += other.shadow_rays;
        self.lb_skipped += other.lb_skipped;
    }
}

/// The relighter as a [`PixelEstimator`]: every pass reads the same [`RelightPass`].
struct Relight<'p, 'a> {
    pass: &'p RelightPass<'a>,
    /// When the passes began, and the wall-clock seconds of the first.
    started: Instant,
    first_pass_seconds: f64,
}

impl PixelPass for Relight<'_, '_> {
    type Work = GatherWork;
    type Note = ();
    type Sums = RelightSums;

    fn shade_pixel(
        &self,
        pixel: usize,
        samples: Range<u32>,
        acc: &mut RelightSums,
        work: &mut GatherWork,
        _note: &mut (),
    ) -> PixelTiming {
        let t = self.pass.gather(pixel, acc, samples, work);
        PixelTiming {
            anchor_ns: t.prepare_ns + t.first_visit_ns,
            sample_ns: t.sample_ns,
        }
    }
}

impl<'p, 'a> PixelEstimator for Relight<'p, 'a> {
    type Work = GatherWork;
    type Note = ();
    type Sums = RelightSums;
    const ADAPTS: bool = true;
    type Pass<'b>
        = Relight<'p, 'a>
    where
        Self: 'b;

    fn pass<R>(&self, _plan: &PassPlan, run: impl FnOnce(&Self) -> R) -> R {
        run(self)
    }

    fn end_pass(&mut self, plan: &PassPlan, _works: &[GatherWork], _sums: &[RelightSums]) {
        if plan.index == 0 {
            self.first_pass_seconds = self.started.elapsed().as_secs_f64();
        }
    }

    /// Shares in proportion to `√(v_i / c_i)` (module docs), pixels without a surface
    /// left out.
    fn shares(
        &self,
        sums: &[RelightSums],
        costs: Option<&[f32]>,
        width: usize,
        height: usize,
    ) -> Option<SampleShares> {
        let v: Vec<Option<f64>> = sums
            .par_iter()
            .map(|s| {
                let (var, mean) = self.pass.lbv_variance(s)?;
                let v = (0..3)
                    .map(|c| var[c] / (mean[c] * mean[c] + RELMSE_FLOOR))
                    .sum::<f64>();
                Some(v / 3.0)
            })
            .collect();
        let shares = SampleShares::from_variances(&v, costs, width, height);
        Some(shares.only(|i| sums[i].surface()))
    }
}

/// Relights `relighter`'s view under `env`, the scene's area lights as they are now and
/// the scene's materials with `overrides` (object id, material) applied
/// ([`Relighter::relight_with`] says what each argument must be), in passes on `threads`
/// workers (`None`: all cores) as the module docs describe. `progress(done, planned)`
/// (pixel `LBV`-samples; `planned` is unknown under a budget and then says the most) is
/// called on the calling thread about every 0.1 s and after each pass; returning `false`
/// stops with [`Error::Interrupted`].
#[allow(clippy::too_many_arguments)]
pub fn relight(
    relighter: &Relighter,
    scene: &Scene,
    env: &EnvMap,
    overrides: &[(u32, Material)],
    cache: Option<&VisibilityCache>,
    light_cache: Option<&VisibilityCache>,
    params: &RelightParams,
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
) -> Result<Relit> {
    let start = Instant::now();
    relighter.relight_with(scene, env, overrides, cache, light_cache, params, |pass| {
        let gbuffer = pass.gbuffer();
        let (width, height) = (gbuffer.width() as usize, gbuffer.height() as usize);
        // Without LBV-samples there is no unbiased part to add to: one pass.
        let budget = params.time_budget.filter(|_| params.lbv_spp > 0);
        let pass_params = PassParams {
            spp: match budget {
                Some(_) => MAX_RELIGHT_SPP,
                None => params.lbv_spp,
            },
            time_budget: budget,
            adaptive: params.adaptive && budget.is_some(),
            // The first pass gives every pixel its `lbv_spp` (SBF's first frame), the
            // budget's passes add to it.
            first_spp: budget.map(|_| params.lbv_spp),
        };
        let mut stopped = false;
        let mut watched = |done: u64, planned: u64| {
            let keep = progress(done, planned);
            stopped |= !keep;
            keep
        };
        let mut estimator = Relight {
            pass,
            started: Instant::now(),
            first_pass_seconds: 0.0,
        };
        let run = run_passes(
            &mut estimator,
            width,
            height,
            &pass_params,
            start,
            threads,
            &mut watched,
        )?;
        if !run.complete || stopped {
            return Err(Error::Interrupted {
                what: "relighting".into(),
            });
        }
        let mut relit = pass.resolve(&run.sums);
        relit.passes = run.passes;
        relit.first_pass_seconds = estimator.first_pass_seconds;
        relit.shadow_rays = run.total.shadow_rays;
        relit.lb_skipped = run.total.lb_skipped;
        relit.seconds = start.elapsed().as_secs_f64();
        Ok(relit)
    })
}

#[cfg(test)]
mod tests;
