//! Stored `V`-samples reused after an edit (module docs of [`super`], "Where `⟨V⟩` comes
//! from" and "Stored samples as `LBV`-samples"): `E_p'[V]` by self-normalised importance
//! sampling with weights `p'/p`, and the stored draws as `LBV`-samples weighted by the
//! balance heuristic against the current density's.

use super::*;

/// `E_p'[V]` of the map's light from the converged samples (self-normalised importance
/// sampling), with what tells how far to trust it, and the samples' share of the unbiased
/// part where they are reused.
#[derive(Clone, Copy, Debug)]
pub(super) struct Reweighted {
    /// `Σ w V / Σ w` (NaN when no sample has weight).
    pub(super) v: f64,
    /// The effective sample count `(Σw)²/Σw²`.
    pub(super) ess: f64,
    /// `1 − Σ w / n` over the `n` stored samples, at least 0: an estimate of the share of
    /// `p'` where `p` drew no sample with a ray (`p = 0 < p'`: light where the old map was
    /// black; or a new sun far from every old draw), whose visibility is unknown.
    pub(super) unseen: f64,
    /// The stored samples as `LBV`-samples of the new lighting, MIS-weighted
    /// ([`ReuseWeights`]; empty without reuse).
    pub(super) reused: [Moments; 3],
    /// `n₁`: the stored samples (0 without reuse).
    pub(super) reuse_n: f64,
    /// The normalization of the converged product (0 without one).
    pub(super) then_total: f64,
}

/// The lights at a pixel as the `V`-samples were drawn: the converged map, area lights and
/// `object`'s material then; with `last`, the map's product too (reused through it as
/// when they were drawn), else none (area lights only).
pub(super) fn converged_lights<'a>(
    c: &'a Converged,
    now: &PixelLights<'a>,
    object: u32,
    last: Option<&mut LastProduct>,
) -> PixelLights<'a> {
    let mut then_sp = now.sp;
    then_sp.material = c.materials[object as usize];
    PixelLights {
        scene: now.scene,
        env: &c.env,
        area_lights: &c.area_lights,
        product: last.and_then(|last| reused_product(&c.env, &then_sp, c.product_level, last)),
        sp: then_sp,
    }
}

/// The balance heuristic (Veach's multi-sample MIS) between the stored `V`-samples, `n₁`
/// draws of the converged density `p₁`, and `n₂` `LBV`-samples of the new density `p₂`:
/// `w₁ = n₁p₁ / (n₁p₁ + n₂p₂)`, `w₂ = 1 − w₁`. `p₁` counts only draws that kept a bit
/// (`LB > 0` under the converged lighting: elsewhere `V` was never traced), so `w₂ = 1`
/// where no stored sample can land. Any weights summing to 1 keep the sum of the two
/// weighted means unbiased, whatever counts are then taken, so `n₂` is the nominal
/// `lbv_spp` for every pass.
#[derive(Clone, Copy, Debug)]
pub(super) struct ReuseWeights {
    pub(super) n1: f64,
    pub(super) n2: f64,
}

impl ReuseWeights {
    /// `w₁` at a direction of densities `p1` (0 where no stored sample lands) and `p2`.
    pub(super) fn stored(&self, p1: f64, p2: f64) -> f64 {
        let a = self.n1 * p1;
        if a > 0.0 {
            a / (a + self.n2 * p2)
        } else {
            0.0
        }
    }
}

/// The density `p₁` of a pixel's stored samples ([`ReuseWeights`]) at the draws of the
/// current densities.
pub(super) struct StoredDensity<'a> {
    /// The lights as converged (with the map's product where `same_cells` is false).
    pub(super) then: PixelLights<'a>,
    pub(super) converged: &'a Converged,
    /// Whether the pixel's material is the converged one.
    pub(super) same_material: bool,
    /// Whether, besides, the product's cells are the converged ones (the same level).
    pub(super) same_cells: bool,
}

impl StoredDensity<'_> {
    /// `p₁` at draw `d` of `light` under `now` (from sampler `rng`; a draw with `LB > 0`):
    /// the converged density there, 0 where `LB` was 0 then (no stored sample there kept
    /// a bit). `then_total` is the converged product's normalization.
    pub(super) fn pdf(
        &self,
        now: &PixelLights,
        light: LightId,
        d: &LightDraw,
        rng: &impl Sampler,
        then_total: f64,
    ) -> f64 {
        let sp = &now.sp;
        // Whether `LB` then, `f · L_then`, is non-zero, `f` the BSDF now (the same): a
        // channel lit now and then has `f ≠ 0` by `d`'s own `LB`, others need `f`.
        let kept = |then_radiance: Vec3| {
            then_radiance != Vec3::ZERO
                && (d.lb_over_p * then_radiance != Vec3::ZERO
                    || sp.material.eval(sp.normal, sp.wo, d.dir) * then_radiance != Vec3::ZERO)
        };
        let c = self.converged;
        match light {
            LightId::Env if self.same_cells => {
                let texel = texel_of(d.dir, c.env.resolution());
                match &now.product {
                    Some(p) if kept(c.env.texel(texel)) => {
                        p.pdf_with_map(&c.env, then_total, d.dir)
                    }
                    _ => 0.0,
                }
            }
            LightId::Env => stored_density(&self.then, d.dir),
            // Drawn by area where the stored sample of the same numbers was: its density.
            LightId::Area(k) if self.same_material => {
                if kept(c.area_lights[k].radiance_at(d.point)) {
                    d.pdf
                } else {
                    0.0
                }
            }
            LightId::Area(_) => self
                .then
                .draw(light, rng)
                .filter(|old| old.ray.is_some())
                .map_or(0.0, |old| old.pdf),
        }
    }
}

/// The converged density `p₁` of the map's stored samples at `dir` (0 where the converged
/// lighting had `LB = 0`, so no sample there kept a bit).
pub(super) fn stored_density(then: &PixelLights, dir: Vec3) -> f64 {
    match then.product.as_ref() {
        Some(product) if then.env_lb(dir) != Vec3::ZERO => product.pdf(then.env, dir),
        _ => 0.0,
    }
}

/// The samples with stored bits (the first [`REWEIGHT_SPP`]) redrawn from their density
/// `p` (the converged map and `object`'s material then, its product reused through `last`
/// as when they were drawn) and weighted by `w = p'/p` ([`Reweighted`]); with `reuse_n2`
/// (`n₂` of [`ReuseWeights`]) also each one's `w₁ LB' V / p` under the new lighting.
pub(super) fn reweighted(
    c: &Converged,
    now: &PixelLights,
    object: u32,
    pixel: usize,
    last: &mut LastProduct,
    reuse_n2: Option<f64>,
) -> Reweighted {
    let none = Reweighted {
        v: f64::NAN,
        ess: 0.0,
        unseen: 1.0,
        reused: [Moments::default(); 3],
        reuse_n: 0.0,
        then_total: 0.0,
    };
    let then = converged_lights(c, now, object, Some(last));
    let Some(p_now) = now.product.as_ref() else {
        return none;
    };
    let (mut sum_w, mut sum_w2, mut sum_wv) = (0.0f64, 0.0f64, 0.0f64);
    let n = c.stored_samples();
    let weights = reuse_n2.map(|n2| ReuseWeights { n1: n as f64, n2 });
    let mut reused = [Moments::default(); 3];
    for s in 0..n {
        let rng = PixelSampler::new(c.seed, pixel as u64, STREAM_V + s as u64);
        let Some(d) = then.draw(LightId::Env, &rng).filter(|d| d.ray.is_some()) else {
            // A draw without a bit is an `LBV`-sample of value 0 (its `w₁` is 0).
            if weights.is_some() {
                Moments::push_each(&mut reused, [0.0; 3]);
            }
            continue;
        };
        let p_new = p_now.pdf(now.env, d.dir);
        let w = p_new / d.pdf;
        let v = c.bit(pixel, 0, s) as u32;
        sum_w += w;
        sum_w2 += w * w;
        sum_wv += w * v as f64;
        if let Some(weights) = weights {
            let x = if v == 1 {
                let w1 = weights.stored(d.pdf, p_new);
                (now.env_lb(d.dir).as_dvec3() * (w1 / d.pdf)).to_array()
            } else {
                [0.0; 3]
            };
            Moments::push_each(&mut reused, x);
        }
    }
    if sum_w > 0.0 {
        Reweighted {
            v: sum_wv / sum_w,
            ess: sum_w * sum_w / sum_w2,
            unseen: (1.0 - sum_w / n.max(1) as f64).max(0.0),
            reused,
            reuse_n: weights.map_or(0.0, |w| w.n1),
            then_total: then.product.as_ref().map_or(0.0, |p| p.normalization()),
        }
    } else {
        none
    }
}

/// The stored samples of area light `k` (index `l` among the lights) at `pixel` as
/// `LBV`-samples of the lights now (`now`), each times its `w₁`
/// ([`ReuseWeights`] with `n₂`). An area light's density does not depend on its radiance
/// or on materials, so a stored draw lands where it did; it kept a bit where `LB > 0`
/// then.
pub(super) fn reused_area(
    c: &Converged,
    now: &PixelLights,
    (l, k): (usize, usize),
    pixel: usize,
    n2: f64,
) -> ([Moments; 3], f64) {
    let n = c.stored_samples();
    let weights = ReuseWeights { n1: n as f64, n2 };
    let mut reused = [Moments::default(); 3];
    for s in 0..n {
        // A set bit is a draw that kept one (`LB > 0` then) and saw the light; any other
        // is an `LBV`-sample of value 0, whatever its weight.
        let x = match c.bit(pixel, l, s) {
            true => {
                let rng = PixelSampler::new(c.seed, pixel as u64, STREAM_V + s as u64);
                now.draw(LightId::Area(k), &rng).map_or([0.0; 3], |d| {
                    let w1 = weights.stored(d.pdf, d.pdf);
                    (d.lb_over_p.as_dvec3() * w1).to_array()
                })
            }
            false => [0.0; 3],
        };
        Moments::push_each(&mut reused, x);
    }
    (reused, weights.n1)
}
