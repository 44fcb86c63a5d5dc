//! The many-light renderer on the pass layer: eq. 6.1's known answers, the furnace, the
//! sampled gather's unbiasedness, determinism over threads and over tiles against pixels,
//! bad parameters, stopping.

use glam::Vec3;

use super::*;
use crate::bsdf::Material;
use crate::camera::GBuffer;
use crate::estimators::many_lights::MAX_SPP;
use crate::lights::vpl::TraceParams;

const ALBEDO: [f32; 3] = [0.5, 0.3, 0.8];

fn no_progress() -> impl FnMut(u64, u64) -> bool + Send {
    |_, _| true
}

fn black() -> EnvMap {
    EnvMap::constant([0.0; 3], 8).unwrap()
}

/// The furnace ([`crate::testing::furnace_sphere`]) of Lambert `ALBEDO`: one bounce of
/// indirect light is `a²` at every point, and a VPL sum has only the tessellation's error.
fn furnace() -> Scene {
    crate::testing::furnace_sphere(4, Material::lambert(ALBEDO).unwrap())
}

fn camera(eye: Vec3, target: Vec3, w: u32, h: u32) -> Camera {
    Camera::look_at(eye, target, Vec3::Z, 60.0, w, h).unwrap()
}

fn trace(scene: &Scene, count: u64, seed: u64) -> VplSet {
    let p = TraceParams {
        count,
        depth: 1,
        seed,
        importance: None,
        lights: true,
    };
    VplSet::trace(scene, &black(), None, &p, Some(2)).unwrap()
}

fn render(
    scene: &Scene,
    cam: &Camera,
    vpls: &VplSet,
    params: &ManyLightParams,
    threads: usize,
) -> ManyLightImage {
    render_many_lights(
        scene,
        &black(),
        cam,
        vpls,
        params,
        None,
        Some(threads),
        &mut no_progress(),
    )
    .unwrap()
}

#[test]
fn one_light_vpl_over_a_plane_gives_eq_6_1() {
    // A Lambert floor at y = 0 lit by one cosine point light at height h facing down:
    // L = ρ/π · Φ/π · cos θ_x cos θ_v / d² = ρ Φ h² / (π² d⁴).
    let rho = 0.6f32;
    let mut scene = Scene::new();
    let v = [
        [-5.0, 0.0, -5.0],
        [5.0, 0.0, -5.0],
        [5.0, 0.0, 5.0],
        [-5.0, 0.0, 5.0],
    ];
    scene
        .add_indexed(
            &v,
            &[[0, 2, 1], [0, 3, 2]],
            Material::lambert([rho; 3]).unwrap(),
            None,
        )
        .unwrap();
    let (h, phi) = (1.5f32, [2.0f32, 1.0, 0.5]);
    let vpls = VplSet::from_lights(&scene, &[[0.3, h, 0.2]], &[[0.0, -1.0, 0.0]], &[phi]).unwrap();
    let cam = camera(Vec3::new(0.0, 4.0, 0.1), Vec3::ZERO, 24, 18);
    let params = ManyLightParams {
        jitter: false,
        ..ManyLightParams::DEFAULT
    };
    let img = render(&scene, &cam, &vpls, &params, 2);
    let g = GBuffer::render(&scene, &cam, 0, false, None).unwrap();
    for (i, px) in img.image.iter().enumerate() {
        let p = Vec3::from(g.position[i]);
        let d2 = (p - Vec3::new(0.3, h, 0.2)).length_squared();
        for c in 0..3 {
            let want = rho * phi[c] * h * h / (std::f32::consts::PI.powi(2) * d2 * d2);
            assert!((px[c] - want).abs() <= 1e-4 * want, "{i}: {px:?} vs {want}");
        }
    }
    assert_eq!(img.stats.shadow_rays, 24 * 18);
    assert_eq!(img.stats.vpls, 1);
    // Without direct light a light VPL adds nothing.
    let indirect = ManyLightParams {
        direct: false,
        ..params
    };
    let dark = render(&scene, &cam, &vpls, &indirect, 2);
    assert!(dark.image.iter().all(|p| *p == [0.0; 3]));
    // A clamp of the geometry term lowers the brightest pixels only.
    let bound = 0.3;
    let clamped = ManyLightParams {
        clamp: Some(bound),
        ..params
    };
    let c = render(&scene, &cam, &vpls, &clamped, 2);
    let mut lowered = 0;
    for (a, b) in c.image.iter().zip(&img.image) {
        assert!(a[0] <= b[0]);
        lowered += (a[0] < b[0]) as u32;
    }
    assert!(lowered > 0 && lowered < 24 * 18, "{lowered}");
}

#[test]
fn furnace_indirect_is_a_squared() {
    let mut scene = furnace();
    scene.build(Default::default());
    let vpls = trace(&scene, 4000, 1);
    let cam = camera(Vec3::new(0.0, 0.1, 0.2), Vec3::new(0.3, -0.2, -1.0), 12, 8);
    let params = ManyLightParams {
        direct: false,
        spp: 2,
        ..ManyLightParams::DEFAULT
    };
    let img = render(&scene, &cam, &vpls, &params, 2);
    for px in &img.image {
        for c in 0..3 {
            let want = ALBEDO[c] * ALBEDO[c];
            // The polyhedron's G varies by a few per cent from the sphere's.
            assert!((px[c] - want).abs() < 0.03 * want, "{px:?} vs {want}");
        }
    }
    let surface = vpls.vpls.iter().filter(|v| v.bounce == 1).count() as u64;
    assert_eq!(img.stats.vpls, surface);
    // One ray per pair, but for the few a facet's tilt turns away (cos <= 0).
    let pairs = surface * 96 * 2;
    assert!(img.stats.shadow_rays <= pairs && img.stats.shadow_rays > pairs * 99 / 100);
    assert_eq!(img.stats.spp, 2);
}

/// Cornell's room at a small size with a set of VPLs.
fn cornell() -> (Scene, EnvMap, Camera, VplSet) {
    let setup = crate::scenes::load("cornell", 1.0, 0).unwrap();
    let mut scene = setup.scene;
    scene.build(Default::default());
    let cam = setup.camera.with_resolution(16, 12).unwrap();
    let p = TraceParams {
        count: 600,
        depth: 1,
        seed: 5,
        importance: None,
        lights: true,
    };
    let vpls = VplSet::trace(&scene, &setup.envmap, None, &p, Some(2)).unwrap();
    (scene, setup.envmap, cam, vpls)
}

/// Every [`Sampling`] is unbiased for the full sum (eq. 6.1): the image's sum per channel
/// within 4 standard errors of the draws (fixed seeds; the pixels' draws are independent).
#[test]
fn sampled_gather_is_unbiased_for_the_full_sum() {
    let (scene, env, cam, vpls) = cornell();
    let run = |gather| {
        let params = ManyLightParams {
            jitter: false,
            spp: 4,
            gather,
            ..ManyLightParams::DEFAULT
        };
        render_many_lights(
            &scene,
            &env,
            &cam,
            &vpls,
            &params,
            None,
            Some(2),
            &mut no_progress(),
        )
        .unwrap()
    };
    let full = run(Gather::Full);
    // Fixed receivers: the full sum is the same every sample.
    assert!(full.variance.iter().all(|v| v.iter().all(|x| *x < 1e-6)));
    let mut se_by = Vec::new();
    for sampling in Sampling::ALL {
        let sampled = run(Gather::Sampled {
            draws: 16,
            sampling,
        });
        let mut se_sum = 0.0;
        for c in 0..3 {
            let (mut diff, mut var) = (0.0f64, 0.0f64);
            for (a, (b, v)) in full
                .image
                .iter()
                .zip(sampled.image.iter().zip(&sampled.variance))
            {
                diff += (b[c] - a[c]) as f64;
                var += v[c] as f64;
            }
            let se = var.sqrt();
            assert!(se > 0.0, "{sampling:?}");
            assert!(
                diff.abs() < 4.0 * se,
                "{sampling:?} channel {c}: {diff} (SE {se})"
            );
            se_sum += se;
        }
        se_by.push(se_sum);
        // A draw whose term is zero (the VPL behind the receiver) traces no ray: only the
        // unoccluded contribution never draws one.
        let draws = 4 * 16 * 16 * 12;
        if sampling == Sampling::Unoccluded {
            assert_eq!(sampled.stats.shadow_rays, draws);
        } else {
            assert!(sampled.stats.shadow_rays < draws, "{sampling:?}");
        }
    }
    // The unoccluded contribution knows the receiver: it is the least noisy.
    assert!(se_by[2] < se_by[0] && se_by[2] < se_by[1], "{se_by:?}");
}

/// Lights at one point facing one way, their fluxes grey: each term is its light's share
/// of the sum, so power sampling is exact (`c_k / p_k = Σ c`) in every pixel; uniform is
/// not, and a light of zero flux is never drawn by power.
#[test]
fn power_sampling_is_exact_for_lights_alike_but_their_flux() {
    let mut scene = Scene::new();
    let v = [
        [-5.0, 0.0, -5.0],
        [5.0, 0.0, -5.0],
        [5.0, 0.0, 5.0],
        [-5.0, 0.0, 5.0],
    ];
    scene
        .add_indexed(
            &v,
            &[[0, 2, 1], [0, 3, 2]],
            Material::lambert([0.6; 3]).unwrap(),
            None,
        )
        .unwrap();
    let fluxes = [[1.0f32; 3], [3.0; 3], [0.0; 3], [0.5; 3]];
    let at = [[0.3f32, 1.5, 0.2]; 4];
    let down = [[0.0f32, -1.0, 0.0]; 4];
    let vpls = VplSet::from_lights(&scene, &at, &down, &fluxes).unwrap();
    let cam = camera(Vec3::new(0.0, 4.0, 0.1), Vec3::ZERO, 12, 9);
    let run = |gather| {
        let params = ManyLightParams {
            jitter: false,
            spp: 2,
            gather,
            ..ManyLightParams::DEFAULT
        };
        render(&scene, &cam, &vpls, &params, 2)
    };
    let full = run(Gather::Full);
    let power = run(Gather::Sampled {
        draws: 3,
        sampling: Sampling::Power,
    });
    for (a, b) in full.image.iter().zip(&power.image) {
        for c in 0..3 {
            assert!((a[c] - b[c]).abs() <= 1e-5 * a[c], "{a:?} vs {b:?}");
        }
    }
    assert!(power.variance.iter().flatten().all(|v| *v <= 1e-10));
    let uniform = run(Gather::Sampled {
        draws: 3,
        sampling: Sampling::Uniform,
    });
    let noisy = uniform.variance.iter().filter(|v| v[0] > 1e-6).count();
    assert!(noisy > 12 * 9 / 2, "{noisy}");
}

#[test]
fn images_are_bit_identical_for_any_thread_count() {
    let (scene, env, cam, vpls) = cornell();
    let sampled = Sampling::ALL.map(|sampling| Gather::Sampled { draws: 8, sampling });
    for gather in std::iter::once(Gather::Full).chain(sampled) {
        let params = ManyLightParams {
            spp: 2,
            gather,
            ..ManyLightParams::DEFAULT
        };
        let go = |t| {
            render_many_lights(
                &scene,
                &env,
                &cam,
                &vpls,
                &params,
                None,
                Some(t),
                &mut no_progress(),
            )
            .unwrap()
        };
        let (a, b) = (go(1), go(2));
        assert_eq!(a.image, b.image);
        assert_eq!(a.variance, b.variance);
    }
}

#[test]
fn bad_parameters_are_named() {
    let (scene, env, cam, vpls) = cornell();
    let name = |params: ManyLightParams, vpls: &VplSet| match render_many_lights(
        &scene,
        &env,
        &cam,
        vpls,
        &params,
        None,
        None,
        &mut no_progress(),
    ) {
        Err(Error::InvalidArgument { name, .. }) => name,
        other => panic!("{:?}", other.map(|i| i.stats)),
    };
    let d = ManyLightParams::DEFAULT;
    assert_eq!(name(ManyLightParams { spp: 0, ..d }, &vpls), "spp");
    assert_eq!(
        name(
            ManyLightParams {
                clamp: Some(-1.0),
                ..d
            },
            &vpls
        ),
        "clamp"
    );
    assert_eq!(
        name(
            ManyLightParams {
                clamp: Some(f32::NAN),
                ..d
            },
            &vpls
        ),
        "clamp"
    );
    let g = Gather::Sampled {
        draws: 0,
        sampling: Sampling::Power,
    };
    assert_eq!(
        name(ManyLightParams { gather: g, ..d }, &vpls),
        "vpl_samples"
    );
    // A per-pixel distribution serves only the per-pixel sampling.
    let uniform = ManyLightParams {
        gather: Gather::Sampled {
            draws: 4,
            sampling: Sampling::Uniform,
        },
        ..d
    };
    let own = Unoccluded::default();
    match render_many_lights(
        &scene,
        &env,
        &cam,
        &vpls,
        &uniform,
        Some(&own),
        None,
        &mut no_progress(),
    ) {
        Err(Error::InvalidArgument { name, .. }) => assert_eq!(name, "sampling"),
        other => panic!("{:?}", other.map(|i| i.stats)),
    }
    assert_eq!(Sampling::parse("power").unwrap(), Sampling::Power);
    for s in Sampling::ALL {
        assert_eq!(Sampling::parse(s.name()).unwrap(), s);
    }
    match Sampling::parse("Power") {
        Err(Error::InvalidArgument { name, .. }) => assert_eq!(name, "sampling"),
        other => panic!("{other:?}"),
    }
    let other = furnace();
    let foreign = trace(&other, 100, 0);
    assert_eq!(name(d, &foreign), "vpls");
}

/// A `false` from progress stops the render within the pass: it says so, keeps the
/// samples taken, and every pixel's estimate is over its own samples.
#[test]
fn a_stopped_render_says_so() {
    let (scene, env, cam, vpls) = cornell();
    let params = ManyLightParams {
        spp: MAX_SPP,
        ..ManyLightParams::DEFAULT
    };
    let pixels = (cam.width * cam.height) as u64;
    let mut calls = 0;
    let mut stop = |done: u64, planned: u64| {
        assert_eq!(planned, MAX_SPP as u64 * pixels);
        assert!(done <= planned);
        calls += 1;
        false
    };
    let img =
        render_many_lights(&scene, &env, &cam, &vpls, &params, None, Some(2), &mut stop).unwrap();
    assert!(calls >= 1);
    assert!(!img.stats.complete);
    assert!(img.stats.samples < MAX_SPP as u64 * pixels);
    assert!(img.stats.spp < MAX_SPP);
    assert_eq!(img.stats.primary_rays, img.stats.samples);
    assert!(img.image.iter().flatten().all(|x| x.is_finite()));
}

/// Full gathers shaded as tiles, sample by sample within a tile, give what pixel by pixel
/// gives (each sample tracing its pixel's whole tile), bit for bit, on an image whose
/// sides are not multiples of the tile.
#[test]
fn tiles_give_the_pixels_values() {
    let (scene, env, cam, vpls) = cornell();
    let cam = cam.with_resolution(10, 7).unwrap();
    for jitter in [true, false] {
        let params = ManyLightParams {
            spp: 3,
            jitter,
            ..ManyLightParams::DEFAULT
        };
        let go = |tiles| {
            render_with(
                &scene,
                &env,
                &cam,
                &vpls,
                &params,
                None,
                Some(2),
                &mut no_progress(),
                tiles,
            )
            .unwrap()
        };
        let (a, b) = (go(true), go(false));
        assert_eq!(a.image, b.image);
        assert_eq!(a.variance, b.variance);
        assert_eq!(a.stats.samples, 3 * 70);
    }
}

/// A budgeted render follows the driver's schedule: every pixel takes a sample, at most
/// `spp`, `spp` in the stats is the least, and the render is complete.
#[test]
fn a_budget_runs_the_driver_schedule() {
    let (scene, env, cam, vpls) = cornell();
    let params = ManyLightParams {
        spp: 64,
        time_budget: Some(0.05),
        ..ManyLightParams::DEFAULT
    };
    let img = render_many_lights(
        &scene,
        &env,
        &cam,
        &vpls,
        &params,
        None,
        Some(2),
        &mut no_progress(),
    )
    .unwrap();
    let pixels = (cam.width * cam.height) as u64;
    assert!(img.stats.complete);
    assert!(img.stats.spp >= 1 && img.stats.spp <= 64);
    assert!(img.stats.samples >= img.stats.spp as u64 * pixels);
    assert!(img.stats.samples <= 64 * pixels);
}
