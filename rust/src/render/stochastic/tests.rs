//! Method "stochastic": its exact mode is method "env" bit for bit; every probability mode
//! with box proxies, and deliberately bad proxies, agree with exact visibility per pixel and
//! over the image within 4 SE; the counters add up; the same bits on 1 and 2 threads; its
//! errors.

use super::*;
use crate::geometry::proxies::{box_triangles, ProxyKind};
use crate::geometry::{Bounds, Mesh};
use crate::render::output::Stat;
use crate::render::registry::method;

fn setup() -> crate::scenes::Setup {
    crate::scenes::load("cornell", 0.25, 0).unwrap()
}

fn small(s: &crate::scenes::Setup) -> Camera {
    s.camera.with_resolution(16, 12).unwrap()
}

fn params(mode: ProbabilityMode, spp: u32) -> StochasticParams {
    StochasticParams {
        spp,
        seed: 3,
        jitter: true,
        time_budget: None,
        mode,
        probe_rays: DEFAULT_PROBE_RAYS,
        exact: false,
    }
}

fn render(
    s: &crate::scenes::Setup,
    cam: &Camera,
    proxies: &ProxySet,
    p: &StochasticParams,
    threads: usize,
) -> StochasticImage {
    render_stochastic(
        &s.scene,
        &s.envmap,
        cam,
        proxies,
        p,
        Some(threads),
        &mut |_, _| true,
    )
    .unwrap()
}

fn int(out: &RenderOutput, name: &str) -> u64 {
    match out.stats.get(name) {
        Some(Stat::Int(i)) => *i,
        other => panic!("{name}: {other:?}"),
    }
}

/// The exact render of the same samples (method "env").
fn env_render(s: &crate::scenes::Setup, cam: &Camera, spp: u32, seed: u64) -> RenderOutput {
    let mut inputs = MethodInputs::new(&s.scene, &s.envmap, View::Camera(cam));
    inputs.spp = Some(spp);
    inputs.threads = Some(2);
    inputs.params.seed = seed;
    method("env")
        .unwrap()
        .render(&inputs, &mut |_, _| true)
        .unwrap()
}

/// Every pixel of `got` and the image mean within 4 SE of `want` (SE from both runs'
/// variances, which are of independent estimates only for the visibility part: the shared
/// light samples make the difference's variance smaller, so the test is conservative).
/// Returns the mean over pixels and channels of `got`'s variance.
fn assert_unbiased(label: &str, got: &RenderOutput, want: &RenderOutput) -> f64 {
    let (mut diff, mut var_sum, mut own) = (0.0f64, 0.0f64, 0.0f64);
    for (p, (((g, w), vg), vw)) in got
        .image
        .iter()
        .zip(&want.image)
        .zip(&got.variance)
        .zip(&want.variance)
        .enumerate()
    {
        for c in 0..3 {
            let d = (g[c] - w[c]) as f64;
            let v = vg[c] as f64 + vw[c] as f64;
            assert!(
                d.abs() <= 4.0 * v.sqrt() + 1e-6,
                "{label}: pixel {p} channel {c}: {} vs {} (se {})",
                g[c],
                w[c],
                v.sqrt()
            );
            diff += d;
            var_sum += v;
            own += vg[c] as f64;
        }
    }
    assert!(
        diff.abs() <= 4.0 * var_sum.sqrt(),
        "{label}: image sum off by {diff} (se {})",
        var_sum.sqrt()
    );
    own / (3 * got.image.len()) as f64
}

#[test]
fn the_exact_mode_is_method_env_bit_for_bit() {
    let s = setup();
    let cam = small(&s);
    let proxies = ProxySet::boxes(&s.scene, None).unwrap();
    let exact = StochasticParams {
        exact: true,
        ..params(ProbabilityMode::Equal, 4)
    };
    let ours = render(&s, &cam, &proxies, &exact, 2).output;
    let env = env_render(&s, &cam, 4, 3);
    let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&ours.image), bits(&env.image));
    assert_eq!(int(&ours, "proxy_rays"), 0);
}

#[test]
fn every_mode_with_box_proxies_is_unbiased_and_counts_add_up() {
    let s = setup();
    let cam = small(&s);
    let proxies = ProxySet::boxes(&s.scene, None).unwrap();
    let spp = 256;
    let want = env_render(&s, &cam, spp, 13);
    for mode in ProbabilityMode::ALL {
        let p = StochasticParams {
            seed: 13,
            ..params(mode, spp)
        };
        s.scene.reset_counters();
        proxies.scene().reset_counters();
        let out = render(&s, &cam, &proxies, &p, 2).output;
        assert_unbiased(mode.name(), &out, &want);
        // Outside proxies never draw term (c); every shadow ray draws one term.
        let Some(Stat::Ints(terms)) = out.stats.get("terms") else {
            panic!("terms")
        };
        let shadow = int(&out, "shadow_rays");
        assert_eq!(terms.iter().sum::<u64>(), shadow, "{mode:?}");
        assert_eq!(terms[2], 0, "{mode:?}");
        // Each probe tests the proxies once and the scene once; each shadow ray at most
        // one proxy query, one split test and one whole-scene test (term (b) only).
        let (probes, proxy_rays) = (int(&out, "probe_rays"), int(&out, "proxy_rays"));
        let (scene_rays, split) = (int(&out, "scene_rays"), int(&out, "split_rays"));
        assert_eq!(probes == 0, mode == ProbabilityMode::Equal, "{mode:?}");
        assert!(proxy_rays <= shadow + probes);
        assert!(
            split <= terms[0],
            "{mode:?}: {split} split tests, {terms:?}"
        );
        assert!(scene_rays >= split + probes);
        assert!(scene_rays - split - probes <= terms[1]);
        // The scenes' own counters saw the same queries.
        let primary = int(&out, "primary_rays");
        assert_eq!(s.scene.counters().rays, primary + scene_rays, "{mode:?}");
        assert_eq!(proxies.scene().counters().rays, proxy_rays, "{mode:?}");
        let Some(Stat::Int(_)) = out.stats.get("scene_triangle_tests") else {
            panic!("scene_triangle_tests")
        };
    }
}

/// A proxy set of `kind` with box `b` standing for each object in `objects`.
fn boxes_at(s: &crate::scenes::Setup, kind: ProxyKind, boxes: &[(u32, Bounds)]) -> ProxySet {
    let meshes = boxes
        .iter()
        .map(|(o, b)| {
            let mut m = Mesh::new();
            m.add_triangles(box_triangles(b), Default::default(), None)
                .unwrap();
            (*o, m)
        })
        .collect();
    ProxySet::from_meshes(&s.scene, kind, meshes).unwrap()
}

fn object_bounds(s: &crate::scenes::Setup, o: u32) -> Bounds {
    let mesh = s.scene.mesh();
    Bounds::of_triangles(&mesh.triangles[mesh.objects[o as usize].triangle_range()])
}

#[test]
fn bad_proxies_cost_variance_not_bias() {
    let s = setup();
    let cam = small(&s);
    let spp = 256;
    let want = env_render(&s, &cam, spp, 5);
    let n = s.scene.num_objects() as u32;
    let good = ProxySet::boxes(&s.scene, None).unwrap();
    // Boxes shifted far off their objects, and each object's box standing for the next
    // object: general proxies (they guarantee nothing).
    let scene_size = s.scene.bounds().extent();
    let far: Vec<(u32, Bounds)> = (0..n)
        .map(|o| {
            let b = object_bounds(&s, o);
            let shift = Vec3::splat(2.0 * scene_size);
            (
                o,
                Bounds {
                    min: b.min + shift,
                    max: b.max + shift,
                },
            )
        })
        .collect();
    let swapped: Vec<(u32, Bounds)> = (0..n)
        .map(|o| ((o + 1) % n, object_bounds(&s, o)))
        .collect();
    let p = StochasticParams {
        seed: 5,
        ..params(ProbabilityMode::Equal, spp)
    };
    let good_var = assert_unbiased("good", &render(&s, &cam, &good, &p, 2).output, &want);
    for (label, set) in [
        ("far", boxes_at(&s, ProxyKind::General, &far)),
        ("swapped", boxes_at(&s, ProxyKind::General, &swapped)),
    ] {
        let var = assert_unbiased(label, &render(&s, &cam, &set, &p, 2).output, &want);
        assert!(
            var > good_var,
            "{label}: variance {var} vs boxes' {good_var}"
        );
    }
}

#[test]
fn one_and_two_threads_give_the_same_bits() {
    let s = setup();
    let cam = small(&s);
    let proxies = ProxySet::boxes(&s.scene, None).unwrap();
    let p = params(ProbabilityMode::Cost, 4);
    let a = render(&s, &cam, &proxies, &p, 1);
    let b = render(&s, &cam, &proxies, &p, 2);
    let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.output.image), bits(&b.output.image));
    assert_eq!(bits(&a.output.variance), bits(&b.output.variance));
    assert_eq!(a.scene_rays, b.scene_rays);
}

#[test]
fn errors_name_the_argument() {
    let s = setup();
    let cam = small(&s);
    let proxies = ProxySet::boxes(&s.scene, None).unwrap();
    let spec = method("stochastic").unwrap();
    let mut inputs = MethodInputs::new(&s.scene, &s.envmap, View::Camera(&cam));
    inputs.spp = Some(1);
    let err = |inputs: &MethodInputs<'_>| spec.render(inputs, &mut |_, _| true).unwrap_err();
    assert!(err(&inputs).to_string().contains("proxies"));
    let with = |probabilities, probe_rays| StochasticInputs {
        proxies: Some(&proxies),
        probabilities,
        probe_rays,
    };
    inputs.stochastic = Some(with(Some("best"), None));
    assert!(err(&inputs).to_string().contains("probabilities"));
    inputs.stochastic = Some(with(None, Some(0)));
    assert!(err(&inputs).to_string().contains("probe_rays"));
    let other = crate::scenes::load("blob", 0.25, 0).unwrap();
    let foreign = ProxySet::boxes(&other.scene, None).unwrap();
    inputs.stochastic = Some(StochasticInputs {
        proxies: Some(&foreign),
        probabilities: None,
        probe_rays: None,
    });
    assert!(err(&inputs).to_string().contains("proxies"));
    inputs.stochastic = Some(with(Some("equal"), Some(2)));
    let out = spec.render(&inputs, &mut |_, _| true).unwrap();
    assert_eq!(out.image.len(), 16 * 12);
}

/// For every shadow ray (from jittered hits toward the light and the map), eq. 8 with
/// splitting averaged over its terms (each `u` inside one term's share) is the ray's exact
/// visibility, for box proxies and for proxies standing for the wrong objects.
#[test]
fn each_rays_expectation_over_the_terms_is_its_visibility() {
    let s = setup();
    let cam = small(&s);
    let n = s.scene.num_objects() as u32;
    let swapped: Vec<(u32, Bounds)> = (0..n)
        .map(|o| ((o + 1) % n, object_bounds(&s, o)))
        .collect();
    let sets = [
        ProxySet::boxes(&s.scene, None).unwrap(),
        boxes_at(&s, ProxyKind::General, &swapped),
    ];
    let mut work = ShadowWork::default();
    let mut rays = 0;
    for proxies in &sets {
        let split = SplitVisibility::new(&s.scene, proxies).unwrap();
        let p = Probabilities::equal(proxies.kind());
        for pixel in 0..(16 * 12) {
            let rngp = PixelSampler::new(11, pixel as u64, 0);
            let mut dd = [Vec3A::ZERO; 1];
            let j = rngp.get2(DIM_PIXEL_JITTER);
            cam.pixel_directions((pixel % 16) as u32, (pixel / 16) as u32, [j], &mut dd);
            let d = Vec3::from(dd[0]);
            let Some(hit) = s
                .scene
                .intersect1(cam.eye, d, f32::INFINITY, &mut work.scene)
            else {
                continue;
            };
            let sp = shading_point_at(&s.scene, &hit, -d);
            let at = split.point(hit.obj, sp.origin, &mut work);
            for k in 0..16 {
                let rng = SampleRng::new(1, pixel as u64, k);
                let (dir, tmax) = if k % 2 == 0 {
                    let uv = Vec2::new(rng.get(1), rng.get(2));
                    let Some(ls) = s.scene.area_lights()[0].sample(sp.origin, rng.get(0), uv)
                    else {
                        continue;
                    };
                    (ls.direction, s.scene.segment_end(ls.distance, ls.point))
                } else {
                    let u = DVec2::new(rng.get(1) as f64, rng.get(2) as f64);
                    let Some((dir, _)) = s.envmap.sample(u) else {
                        continue;
                    };
                    (dir, f32::INFINITY)
                };
                if sp.normal.dot(dir) <= 0.0 || tmax <= 0.0 {
                    continue;
                }
                let exact = split.exact(sp.origin, dir, tmax, &mut work) as u8 as f64;
                let (mut mean, mut lo) = (0.0, 0.0);
                for pt in p.p {
                    if pt > 0.0 {
                        let u = lo + 0.5 * pt;
                        mean += pt * split.estimate(&p, u, &at, sp.origin, dir, tmax, &mut work);
                    }
                    lo += pt;
                }
                assert!(
                    (mean - exact).abs() < 1e-9,
                    "pixel {pixel} ray {k}: {mean} vs {exact}"
                );
                rays += 1;
            }
        }
    }
    assert!(rays > 1000, "{rays}");
}
