//! The relighter on the pass layer: its first visit at every pixel, even counts under a
//! budget equal to a run asked for them, adaptive counts that leave pixels without a
//! surface alone, thread-count independence and stopping.

use super::*;
use crate::camera::GBuffer;
use crate::estimators::decoupled::VisibilitySource;
use crate::scenes::Setup;

const W: u32 = 24;
const H: u32 = 18;

/// Garage (a sky the camera sees, the sun through a window) with 32 `V`-samples per pixel.
fn garage() -> (Setup, Relighter) {
    let setup = crate::scenes::load("garage", 0.25, 0).unwrap();
    let camera = setup.camera.with_resolution(W, H).unwrap();
    let gbuffer = GBuffer::render(&setup.scene, &camera, 0, false, Some(2)).unwrap();
    let mut rl = Relighter::new(&setup.scene, gbuffer, VisibilitySource::Pixels).unwrap();
    rl.converge_visibility(
        &setup.scene,
        &setup.envmap,
        32,
        0,
        RelightParams::DEFAULT.product_level,
        Some(2),
        None,
        &mut |_, _| true,
    )
    .unwrap();
    (setup, rl)
}

fn run(setup: &Setup, rl: &Relighter, params: &RelightParams, threads: usize) -> Result<Relit> {
    relight(
        rl,
        &setup.scene,
        &setup.envmap,
        &[],
        None,
        None,
        params,
        Some(threads),
        &mut |_, _| true,
    )
}

/// Every field of two results but their timings.
fn assert_same(a: &Relit, b: &Relit) {
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let rgb = |v: &[[f32; 3]]| bits(v.as_flattened());
    assert_eq!(rgb(&a.image), rgb(&b.image));
    assert_eq!(rgb(&a.variance), rgb(&b.variance));
    assert_eq!(rgb(&a.error_bound), rgb(&b.error_bound));
    assert_eq!(bits(&a.t), bits(&b.t));
    assert_eq!(bits(&a.bound), bits(&b.bound));
    assert_eq!(bits(&a.visibility), bits(&b.visibility));
    assert_eq!(bits(&a.effective_samples), bits(&b.effective_samples));
    assert_eq!(a.lbv_counts, b.lbv_counts);
    assert_eq!(a.shadow_rays, b.shadow_rays);
    assert_eq!(a.lb_skipped, b.lb_skipped);
}

/// Without `LBV`-samples the one pass still visits every pixel (what it sees, `⟨V⟩`, its
/// `LB`-samples): the image is `⟨LB⟩⟨V⟩` alone, lit, with no ray traced; a budget adds no
/// pass.
#[test]
fn without_lbv_samples_every_pixel_is_still_visited() {
    let (setup, rl) = garage();
    let params = RelightParams {
        lb_spp: 8,
        lbv_spp: 0,
        time_budget: Some(0.05),
        ..RelightParams::DEFAULT
    };
    let r = run(&setup, &rl, &params, 2).unwrap();
    assert_eq!((r.passes, r.shadow_rays, r.lbv_spp), (1, 0, 0));
    assert!(r.lbv_counts.iter().all(|&n| n == 0));
    let surface: Vec<bool> = r.t.iter().map(|t| t.is_finite()).collect();
    assert!(surface.iter().any(|&s| s));
    // Surfaces lean on the decoupled part alone (t = 1) and are lit.
    assert!(r.t.iter().filter(|t| t.is_finite()).all(|&t| t == 1.0));
    assert!(r.image.iter().zip(&surface).any(|(p, &s)| s && p[0] > 0.0));
}

/// A budget with even counts: a probe, then passes; every surface pixel ends with the same
/// count, and the result equals a run without a budget asked for it, on any thread count.
#[test]
fn even_counts_under_a_budget_equal_a_run_asked_for_them() {
    let (setup, rl) = garage();
    let params = RelightParams {
        lb_spp: 8,
        lbv_spp: 4,
        time_budget: Some(0.1),
        adaptive: false,
        ..RelightParams::DEFAULT
    };
    let budgeted = run(&setup, &rl, &params, 2).unwrap();
    assert!(budgeted.passes >= 2);
    let taken = budgeted.lbv_spp;
    assert!(taken >= 1);
    assert!(budgeted.lbv_counts.iter().all(|&n| n == 0 || n == taken));
    assert!(budgeted.first_pass_seconds > 0.0 && budgeted.first_pass_seconds < budgeted.seconds);
    let asked = RelightParams {
        lbv_spp: taken,
        time_budget: None,
        ..params
    };
    let a = run(&setup, &rl, &asked, 1).unwrap();
    assert_eq!(a.passes, 1);
    assert_same(&a, &budgeted);
    assert_same(&a, &run(&setup, &rl, &asked, 3).unwrap());
}

/// Adaptive counts under a budget: pixels without a surface take none, others differ.
#[test]
fn adaptive_counts_skip_pixels_without_a_surface() {
    let (setup, rl) = garage();
    let params = RelightParams {
        lb_spp: 8,
        lbv_spp: 4,
        time_budget: Some(0.2),
        ..RelightParams::DEFAULT
    };
    let r = run(&setup, &rl, &params, 2).unwrap();
    assert!(r.passes >= 2);
    for (n, t) in r.lbv_counts.iter().zip(r.t.iter()) {
        assert_eq!(*n == 0, !t.is_finite(), "count {n}, t {t}");
    }
    assert!(r.lbv_spp as f64 > r.lbv_spp_mean);
}

/// A `false` from progress stops the render with [`Error::Interrupted`].
#[test]
fn progress_can_stop_it() {
    let (setup, rl) = garage();
    let params = RelightParams::DEFAULT;
    let out = relight(
        &rl,
        &setup.scene,
        &setup.envmap,
        &[],
        None,
        None,
        &params,
        Some(1),
        &mut |_, _| false,
    );
    assert!(matches!(out, Err(Error::Interrupted { .. })));
}
