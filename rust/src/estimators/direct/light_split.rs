//! Light draws per sample chosen from the anchors (splitting,
//! the renderer's `RenderParams::auto_light_samples`).
//!
//! A sample's value is what its jittered primary ray decides (the hit) plus the noise of
//! its light draws about it. Where a pixel's rays all land on its anchor's surface, the
//! first part hardly varies, and averaging several draws per sample saves the rest of a
//! sample (primary ray, hit, mixture set-up) for each draw. Where the hits differ from ray
//! to ray (grass, hair, thin parts, silhouettes of small things), a draw is better spent
//! on a sample of its own.
//!
//! The view's *edge share* measures which: the share of the pixels that see a surface
//! whose anchor and eight neighbours' anchors are not all on one object with normals
//! within the material's product tolerance (the test that decides whether a sample
//! shares its anchor's product; the image border counts as an edge). Below
//! [`SPLIT_EDGE_SHARE`] every sample takes [`SPLIT_DRAWS`] draws, else one. The choice
//! reads the G-buffer only, never samples, and holds for the whole render, so every
//! pixel's draws are one run of one quasi-random stream (choosing counts per pixel from a
//! pilot mixed counts within pixels and lost the Sobol points' stratification; choosing
//! them per pixel from the anchors starved the silhouettes of scenes whose edges want
//! draws too: benches/HISTORY.md).
//!
//! How many, where the view splits, its probe pass decides ([`draws_after_probe`]): from
//! the variance of its samples' values, of their first draws alone and the draws' share
//! of the samples' CPU time, the two-stage optimum `sqrt((c₀ / c₁)(V_w / V_b))`, at most
//! [`SPLIT_DRAWS`]. Where a draw is dear beside the rest of a sample and the hits vary
//! (the Cornell box: two shadow rays a draw, a primary ray into 1,262 triangles, the
//! light's edge on the ceiling), fewer; where nearly all of a sample's variance is the
//! light's (garage, panels, dynamics, blob), all eight. Deciding after the pilot pass
//! instead, on every pixel, mixed counts within the pixels and lost 1.1-1.5x
//! (benches/HISTORY.md).
//!
//! Measured at 1 s on the suite, 160x120, eight draws everywhere against one
//! (`benches/peer_mitsuba.py --methods product product:8`, relMSE over Mitsuba's, edge
//! share in brackets): garage (0.11) 0.22 → 0.14, panels (0.11) 0.47 → 0.38, room (0.13)
//! 0.83 → 0.61, dynamics (0.13) 0.13 → 0.12, blob (0.24) 0.13 → 0.11, meshes (0.25) 0.16
//! → 0.15; garden (1.00) 0.46 → 1.55, strands (0.66) 0.34 → 0.68, instances (0.59) 0.22
//! → 0.33, hairball (0.44) 0.41 → 0.61, scales (0.30) 0.19 → 0.23. Cornell's box (0.12)
//! is the exception, 0.010 → 0.014 under its area light, far below Mitsuba either way.
//! The control variate follows the same pattern (`cv` against `cv:8`, same size and
//! budget): garage 0.16 → 0.13, room 0.36 → 0.32, panels 0.22 → 0.17, blob 0.10 → 0.09;
//! garden 0.45 → 1.43, strands 0.40 → 0.70, hairball 0.47 → 0.62, instances 0.26 → 0.37,
//! scales 0.19 → 0.26; meshes 0.15 → 0.17 and cornell 0.01 → 0.02 lose a little.

use glam::Vec3;

use crate::camera::GBuffer;
use crate::geometry::Scene;

/// Light draws per sample where the view splits.
pub const SPLIT_DRAWS: u32 = 8;

/// Largest edge share at which the view splits (between meshes' 0.25, where eight draws
/// tie with one, and scales' 0.30, where they lose 1.2x).
pub const SPLIT_EDGE_SHARE: f64 = 0.275;

/// The edge share of `anchors` of `scene` (module docs): edge pixels over pixels that see
/// a surface; 1 when none does.
pub fn edge_share(anchors: &GBuffer, scene: &Scene) -> f64 {
    let (w, h) = (
        anchors.camera.width as usize,
        anchors.camera.height as usize,
    );
    // Per object, the cosine of its material's product tolerance.
    let cos_match: Vec<f32> = (scene.mesh().objects.iter())
        .map(|o| o.material.product_tolerance().cos())
        .collect();
    let normal = |i: usize| Vec3::from(anchors.normal[i]);
    let (mut surfaces, mut edges) = (0u64, 0u64);
    for i in 0..w * h {
        let object = anchors.object[i];
        if object < 0 {
            continue;
        }
        surfaces += 1;
        let (x, y) = (i % w, i / w);
        if x == 0 || y == 0 || x + 1 == w || y + 1 == h {
            edges += 1;
            continue;
        }
        let cos_match = cos_match[object as usize];
        let n = normal(i);
        let smooth = (y - 1..=y + 1).all(|yy| {
            (x - 1..=x + 1).all(|xx| {
                let j = yy * w + xx;
                anchors.object[j] == object && normal(j).dot(n) >= cos_match
            })
        });
        edges += !smooth as u64;
    }
    if surfaces == 0 {
        1.0
    } else {
        edges as f64 / surfaces as f64
    }
}

/// Light draws per sample for a view of edge share `share`.
pub fn draws_for(share: f64) -> u32 {
    if share < SPLIT_EDGE_SHARE {
        SPLIT_DRAWS
    } else {
        1
    }
}

/// What the probe pass of a render that splits measures of its samples, for
/// [`draws_from`]: relMSE-weighted variances between a pixel's samples (each pixel's
/// channels weighted by `1 / (mean² + 10⁻²)`, summed over the probed pixels) and CPU time.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SplitProbe {
    /// Of the samples' values, the mean of their `k` light draws.
    pub all: f64,
    /// Of the samples' values had they stopped after their first draw (a one-draw
    /// estimate of the same pixel, drawn from the same samples).
    pub first: f64,
    /// CPU nanoseconds of the samples' light draws, and of the samples in all.
    pub draw_ns: u64,
    pub sample_ns: u64,
    /// Samples measured.
    pub samples: u64,
}

impl std::ops::AddAssign for SplitProbe {
    fn add_assign(&mut self, o: Self) {
        self.all += o.all;
        self.first += o.first;
        self.draw_ns += o.draw_ns;
        self.sample_ns += o.sample_ns;
        self.samples += o.samples;
    }
}

/// The light draws per sample that the probe's `k`-draw samples say cost least for
/// their variance: `sqrt((c₀ / c₁) · (V_w / V_b))`, the optimum of two-stage sampling
/// (Cochran, *Sampling Techniques*, 3rd ed., 1977, §10.6) for a sample of variance
/// `V_b + V_w / k` (`V_b` what the jittered hit decides, `V_w` one draw's noise about it)
/// and cost `c₀ + k c₁` (`c₁` a draw with its shadow rays, `c₀` the rest: primary ray,
/// hit, mixture set-up). From the variances of one draw (`V_b + V_w`) and of `k`:
/// `V_w = (first − all) k / (k − 1)`. Stratified draws make `all` smaller than `V_w / k`
/// alone would, which overstates `V_w` and errs toward more draws. `None` when the probe
/// cannot tell (no variance left to the hits, no time measured): keep `k`.
pub fn draws_from(probe: &SplitProbe, k: u32) -> Option<f64> {
    probe_ratios(probe, k).map(|r| r.draws())
}

/// The two ratios [`draws_from`] weighs: `c₀ / c₁`, measured in CPU time (so it varies
/// with the machine and its load), and `V_w / V_b`, from the samples' values alone (so a
/// fixed function of the seed). `None` where [`draws_from`] is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProbeRatios {
    /// The rest of a sample's cost over one draw's, `c₀ / c₁`.
    pub cost: f64,
    /// One draw's variance about the hit over the hit's own, `V_w / V_b`.
    pub variance: f64,
}

impl ProbeRatios {
    /// The two-stage optimum `sqrt((c₀ / c₁) · (V_w / V_b))`.
    pub fn draws(&self) -> f64 {
        (self.cost * self.variance).sqrt()
    }
}

/// [`ProbeRatios`] of `probe`'s `k`-draw samples (see [`draws_from`]).
pub fn probe_ratios(probe: &SplitProbe, k: u32) -> Option<ProbeRatios> {
    if k < 2 || probe.samples == 0 || probe.draw_ns == 0 {
        return None;
    }
    let kf = k as f64;
    let v_w = (probe.first - probe.all) * kf / (kf - 1.0);
    let v_b = probe.first - v_w;
    let c1 = probe.draw_ns as f64 / kf;
    let c0 = probe.sample_ns.saturating_sub(probe.draw_ns) as f64;
    (v_b > 0.0 && v_w > 0.0 && c0 > 0.0).then(|| ProbeRatios {
        cost: c0 / c1,
        variance: v_w / v_b,
    })
}

/// The count in `1..=k` for an optimum of [`draws_from`] (`k` when the probe could not
/// tell).
pub fn draws_after_probe(optimum: Option<f64>, k: u32) -> u32 {
    optimum.map_or(k, |d| (d.round() as u32).clamp(1, k))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes;

    fn share(name: &str) -> f64 {
        let setup = scenes::load(name, 1.0, 0).unwrap();
        let cam = setup.camera.with_resolution(80, 60).unwrap();
        let g = GBuffer::render(&setup.scene, &cam, 0, false, None).unwrap();
        edge_share(&g, &setup.scene)
    }

    #[test]
    fn grass_is_all_edges_and_a_garage_mostly_smooth_surfaces() {
        // Every garden pixel sees blades whose neighbours are other blades.
        let garden = share("garden");
        assert!(garden > 0.95, "{garden}");
        assert_eq!(draws_for(garden), 1);
        // Garage: floor and walls; its edges are the silhouettes and the image border
        // (at 80x60 the border alone is 276 / 4800 = 5.8% of the pixels).
        let garage = share("garage");
        assert!(garage > 0.058 && garage < 0.25, "{garage}");
        assert_eq!(draws_for(garage), SPLIT_DRAWS);
        assert_eq!(draws_for(SPLIT_EDGE_SHARE), 1);
    }

    #[test]
    fn a_count_given_excludes_the_choice() {
        use crate::estimators::direct::Method;
        use crate::render::RenderParams;
        let auto = RenderParams {
            auto_light_samples: true,
            ..RenderParams::with(Method::Product, 8)
        };
        assert!(auto.validate().is_ok());
        let both = RenderParams {
            light_samples: 2,
            ..auto
        };
        let err = both.validate().unwrap_err().to_string();
        assert!(err.contains("light_samples"), "{err}");
    }

    #[test]
    fn the_probe_takes_the_two_stage_optimum() {
        // One draw: V_b + V_w = 2.5; eight: V_b + V_w / 8 = 0.75. So V_w = 2, V_b = 0.5;
        // a draw costs 100 ns, the rest of a sample 200: sqrt(2 · 4) = 2.83.
        let probe = SplitProbe {
            all: 0.75,
            first: 2.5,
            draw_ns: 800,
            sample_ns: 1000,
            samples: 1,
        };
        let k = draws_from(&probe, 8).unwrap();
        assert!((k - 8f64.sqrt()).abs() < 1e-12, "{k}");
        assert_eq!(draws_after_probe(draws_from(&probe, 8), 8), 3);
        // Dearer primary work: more draws, never more than the view's count.
        let dear = SplitProbe {
            sample_ns: 100_000,
            ..probe
        };
        assert_eq!(draws_after_probe(draws_from(&dear, 8), 8), 8);
        // Draws that explain all of the variance (or more, when stratified) leave nothing
        // to the hits: the probe cannot tell, the count stays.
        let light_only = SplitProbe { all: 0.2, ..probe };
        assert_eq!(draws_from(&light_only, 8), None);
        assert_eq!(draws_after_probe(draws_from(&light_only, 8), 8), 8);
        // Draws that cost nothing beside the rest: all of them, though the hits make
        // nearly all of the variance; a rest that costs nothing: one.
        let free = SplitProbe {
            draw_ns: 1,
            sample_ns: 1_000_000,
            all: 2.4,
            ..probe
        };
        assert_eq!(draws_after_probe(draws_from(&free, 8), 8), 8);
        let cheap_rest = SplitProbe {
            draw_ns: 1_000_000,
            sample_ns: 1_000_001,
            ..probe
        };
        assert_eq!(draws_after_probe(draws_from(&cheap_rest, 8), 8), 1);
        assert_eq!(draws_from(&SplitProbe::default(), 8), None);
        assert_eq!(draws_from(&probe, 1), None);
    }

    #[test]
    fn a_view_of_no_surface_has_share_one() {
        let setup = scenes::load("garage", 1.0, 0).unwrap();
        // Looking straight up into the sky above the garage.
        let cam = crate::camera::Camera::look_at(
            Vec3::new(0.0, 50.0, 0.0),
            Vec3::new(0.0, 100.0, 0.1),
            Vec3::Y,
            20.0,
            8,
            6,
        )
        .unwrap();
        let g = GBuffer::render(&setup.scene, &cam, 0, false, None).unwrap();
        assert_eq!(g.object.iter().filter(|&&o| o >= 0).count(), 0);
        assert_eq!(edge_share(&g, &setup.scene), 1.0);
    }
}
