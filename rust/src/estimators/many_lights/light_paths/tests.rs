use super::*;

const ALBEDO: [f32; 3] = [0.5, 0.3, 0.8];

/// The furnace ([`crate::testing::furnace_sphere`]) of Lambert `ALBEDO` under a black map:
/// every photon hits the sphere again, and each hit keeps `ALBEDO` of its flux.
fn furnace() -> Scene {
    crate::testing::furnace_sphere(3, Material::lambert(ALBEDO).unwrap())
}

fn black() -> EnvMap {
    EnvMap::constant([0.0; 3], 8).unwrap()
}

fn camera() -> Camera {
    Camera::look_at(
        Vec3::new(0.0, 0.1, 0.2),
        Vec3::new(0.3, -0.2, -1.0),
        Vec3::Y,
        60.0,
        16,
        12,
    )
    .unwrap()
}

fn params(count: u64, depth: u32, importance: bool) -> TraceParams {
    TraceParams {
        count,
        depth,
        seed: 3,
        importance: importance.then_some(Importance::DEFAULT),
        lights: true,
    }
}

/// Sum of the fluxes of generation `bounce` and its standard error over the set's paths
/// (each path holds at most one VPL of a generation; the others add zero).
fn flux_and_se(set: &VplSet, bounce: u32) -> (DVec3, DVec3) {
    let p = set.stats.paths as f64;
    let (mut s, mut s2) = (DVec3::ZERO, DVec3::ZERO);
    for v in set.vpls.iter().filter(|v| v.bounce == bounce) {
        let x = v.flux.as_dvec3();
        s += x;
        s2 += x * x;
    }
    let var = (s2 - s * s / p) * (p / (p - 1.0));
    (s, var.max(DVec3::ZERO).map(f64::sqrt))
}

#[test]
fn furnace_flux_is_the_lights_power_times_the_albedo_per_bounce() {
    let mut scene = furnace();
    scene.build(Default::default());
    let power = DVec3::from_array(scene.area_lights()[0].power());
    let set = VplSet::trace(&scene, &black(), None, &params(20_000, 3, false), Some(2)).unwrap();
    let a = Vec3::from_array(ALBEDO).as_dvec3();
    // Every photon hits the sphere, and a Lambert bounce keeps exactly `a` of the flux:
    // the first two generations are exact up to rounding.
    for (bounce, want) in [(0, power), (1, power), (2, a * power)] {
        let got = set.total_flux(bounce);
        assert!(
            ((got - want).abs() / want).max_element() < 1e-4,
            "bounce {bounce}: {got} vs {want}"
        );
    }
    // The third is cut by Russian roulette: unbiased within its standard error.
    let (got, se) = flux_and_se(&set, 3);
    let want = a * a * power;
    for c in 0..3 {
        assert!(
            (got[c] - want[c]).abs() < 4.0 * se[c],
            "{got} vs {want} (SE {se})"
        );
    }
    assert!(se.max_element() > 0.0);
    // About the VPLs asked for: each path holds its light VPL and up to three hits.
    let n = set.len() as f64;
    assert!((n - 20_000.0).abs() < 0.05 * 20_000.0, "{n}");
}

#[test]
fn a_constant_map_sends_two_pi_l_a_onto_a_plane() {
    // A 2 x 2 plane under a constant map of radiance L: each side receives π L A.
    let v = [
        [-1.0, 0.0, -1.0],
        [1.0, 0.0, -1.0],
        [1.0, 0.0, 1.0],
        [-1.0, 0.0, 1.0],
    ];
    let f = [[0, 2, 1], [0, 3, 2]];
    let mut scene = Scene::new();
    scene
        .add_indexed(&v, &f, Material::lambert([0.5; 3]).unwrap(), None)
        .unwrap();
    scene.build(Default::default());
    let l = [0.5f32, 1.0, 2.0];
    let env = EnvMap::constant(l, 16).unwrap();
    let set = VplSet::trace(&scene, &env, None, &params(40_000, 1, false), Some(2)).unwrap();
    let (got, se) = flux_and_se(&set, 1);
    let want = Vec3::from_array(l).as_dvec3() * 2.0 * std::f64::consts::PI * 4.0;
    for c in 0..3 {
        assert!(
            (got[c] - want[c]).abs() < 4.0 * se[c],
            "{got} vs {want} (SE {se})"
        );
    }
    assert!((se / want).max_element() < 0.05, "{se}");
    // The light VPLs' irradiance on a surface facing them, summed, is the map's ∫ L dω.
    let e: DVec3 = set.total_flux(0) / set.disk_area as f64;
    let total = DVec3::from_array(env.total_power());
    assert!(
        ((e - total).abs() / total).max_element() < 1e-3,
        "{e} vs {total}"
    );
}

#[test]
fn importance_keeps_the_flux_unbiased_and_aims_at_the_view() {
    let mut scene = furnace();
    scene.build(Default::default());
    let power = DVec3::from_array(scene.area_lights()[0].power());
    let cam = camera();
    let set = VplSet::trace(
        &scene,
        &black(),
        Some(&cam),
        &params(20_000, 1, true),
        Some(2),
    )
    .unwrap();
    let (got, se) = flux_and_se(&set, 1);
    for c in 0..3 {
        assert!(
            (got[c] - power[c]).abs() < 4.0 * se[c],
            "{got} vs {power} (SE {se})"
        );
    }
    assert!(set.stats.mean_contribution > 0.0);
    assert!(set.stats.rejected > 0, "{:?}", set.stats);
    assert!(set.stats.shadow_rays > 0);
    let n = set.len() as f64;
    assert!((n - 20_000.0).abs() < 0.05 * 20_000.0, "{n}");
}

#[test]
fn sets_are_bit_identical_for_any_thread_count() {
    let mut scene = furnace();
    scene.build(Default::default());
    let cam = camera();
    for importance in [false, true] {
        let p = params(5_000, 2, importance);
        let a = VplSet::trace(&scene, &black(), Some(&cam), &p, Some(1)).unwrap();
        let b = VplSet::trace(&scene, &black(), Some(&cam), &p, Some(2)).unwrap();
        assert_eq!(a.vpls, b.vpls);
        assert_eq!(a.stats.paths, b.stats.paths);
    }
}

#[test]
fn bad_parameters_and_unlit_setups_are_named() {
    let mut scene = furnace();
    scene.build(Default::default());
    let name = |r: Result<VplSet>| match r {
        Err(Error::InvalidArgument { name, .. }) => name,
        other => panic!("{other:?}"),
    };
    let env = black();
    assert_eq!(
        name(VplSet::trace(
            &scene,
            &env,
            None,
            &params(0, 1, false),
            None
        )),
        "count"
    );
    assert_eq!(
        name(VplSet::trace(
            &scene,
            &env,
            None,
            &params(10, 0, false),
            None
        )),
        "depth"
    );
    assert_eq!(
        name(VplSet::trace(
            &scene,
            &env,
            None,
            &params(10, 1, true),
            None
        )),
        "importance"
    );
    let mut p = params(10, 1, true);
    p.importance = Some(Importance {
        epsilon: 0.0,
        ..Importance::DEFAULT
    });
    assert_eq!(
        name(VplSet::trace(&scene, &env, Some(&camera()), &p, None)),
        "epsilon"
    );
    let mut dark = Scene::new();
    dark.add_indexed(
        &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        &[[0, 1, 2]],
        Material::DEFAULT,
        None,
    )
    .unwrap();
    dark.build(Default::default());
    assert_eq!(
        name(VplSet::trace(
            &dark,
            &env,
            None,
            &params(10, 1, false),
            None
        )),
        "setup"
    );
    let nan = VplSet::from_lights(
        &dark,
        &[[0.0; 3]],
        &[[0.0, 1.0, 0.0]],
        &[[f32::NAN, 0.0, 0.0]],
    );
    assert_eq!(name(nan), "flux");
    let zero = VplSet::from_lights(&dark, &[[0.0; 3]], &[[0.0; 3]], &[[1.0; 3]]);
    assert_eq!(name(zero), "normals");
}

#[test]
fn without_light_vpls_the_count_is_of_surface_vpls() {
    let mut scene = furnace();
    scene.build(Default::default());
    let power = DVec3::from_array(scene.area_lights()[0].power());
    for importance in [false, true] {
        let mut p = params(8_000, 1, importance);
        p.lights = false;
        let set = VplSet::trace(&scene, &black(), Some(&camera()), &p, Some(2)).unwrap();
        assert!(set.vpls.iter().all(|v| v.kind == VplKind::Surface));
        let n = set.len() as f64;
        assert!((n - 8_000.0).abs() < 0.05 * 8_000.0, "{n}");
        let (got, se) = flux_and_se(&set, 1);
        for c in 0..3 {
            let tol = if importance {
                4.0 * se[c]
            } else {
                1e-4 * power[c]
            };
            assert!(
                (got[c] - power[c]).abs() <= tol,
                "{got} vs {power} (SE {se})"
            );
        }
    }
}

/// Tracing polls the current stop per chunk of paths, with importance (pilot, view points,
/// the set) and without: a set stop fails it with `Interrupted`, and the same call outside
/// the stop's scope gives the set a call never stopped gives.
#[test]
fn tracing_stops_when_its_stop_is_set() {
    let mut scene = furnace();
    scene.build(Default::default());
    let cam = camera();
    let stop = crate::stop::Stop::new();
    stop.set();
    for importance in [false, true] {
        let p = params(5_000, 2, importance);
        let traced = || VplSet::trace(&scene, &black(), Some(&cam), &p, Some(2));
        let e = stop.scope(traced).unwrap_err();
        assert!(matches!(e, Error::Interrupted { .. }), "{e}");
        let (a, b) = (traced().unwrap(), traced().unwrap());
        assert_eq!(a.vpls, b.vpls);
        assert!(!a.vpls.is_empty());
    }
}

/// A 2 x 2 Lambert plane at `y = 0` (white), with optionally a quad light above it.
fn lit_plane(light: bool) -> Scene {
    let mut scene = Scene::new();
    let v = [
        [-1.0, 0.0, -1.0],
        [1.0, 0.0, -1.0],
        [1.0, 0.0, 1.0],
        [-1.0, 0.0, 1.0],
    ];
    scene
        .add_indexed(
            &v,
            &[[0, 2, 1], [0, 3, 2]],
            Material::lambert([1.0; 3]).unwrap(),
            None,
        )
        .unwrap();
    if light {
        // Facing down (-y) at height 1, offset in x: points see it at many angles.
        let q = [
            [0.2, 1.0, -0.3],
            [0.8, 1.0, -0.3],
            [0.8, 1.0, 0.3],
            [0.2, 1.0, 0.3],
        ];
        scene.add_area_light(&q, [2.0, 1.0, 0.5], None).unwrap();
    }
    scene.build(Default::default());
    scene
}

/// A white Lambert receiver at `p` with normal `n` (not on any surface: nothing is in
/// the way of its shadow rays in [`lit_plane`] when `p` is above the plane).
fn receiver(scene: &Scene, p: Vec3, n: Vec3) -> Receiver {
    Receiver::new(
        scene,
        ShadingPoint {
            origin: p,
            normal: n,
            wo: n,
            material: Material::lambert([1.0; 3]).unwrap(),
        },
    )
}

/// A map with a smooth sky, a dark lower half and a bright small sun.
fn sky_map(res: u32) -> EnvMap {
    use crate::sampling::octahedral::texel_center;
    let sun = Vec3::new(0.4, 0.6, -0.3).normalize();
    let texels = (0..res * res)
        .map(|i| {
            let d = texel_center(glam::UVec2::new(i % res, i / res), res);
            let sky = 0.5 + 0.5 * d.y.max(0.0) + 0.2 * d.x;
            let s = if d.dot(sun) > 0.995 { 200.0 } else { 0.0 };
            [sky + s, 0.8 * sky + s, 0.3 + 0.1 * d.z + s]
        })
        .collect();
    EnvMap::from_octahedral(res, texels).unwrap()
}

/// `∫ L(ω) max(0, n · ω) dω` by brute force: 8 x 8 points in every texel of the map.
fn cosine_integral(env: &EnvMap, n: Vec3) -> DVec3 {
    use crate::sampling::octahedral::{square_to_sphere, texel_solid_angle};
    let res = env.resolution();
    let sub = 8u32;
    let w = texel_solid_angle(res) / (sub * sub) as f64;
    let mut sum = DVec3::ZERO;
    for t in 0..res * res {
        let l = Vec3::from(env.texels()[t as usize]).as_dvec3();
        let (x, y) = (t % res, t / res);
        for s in 0..sub * sub {
            let uv = glam::Vec2::new(
                (x as f32 + ((s % sub) as f32 + 0.5) / sub as f32) / res as f32,
                (y as f32 + ((s / sub) as f32 + 0.5) / sub as f32) / res as f32,
            );
            let c = n.dot(square_to_sphere(uv)).max(0.0) as f64;
            sum += l * (c * w);
        }
    }
    sum
}

#[test]
fn map_texels_as_directional_lights_converge_to_the_cosine_integral() {
    let scene = lit_plane(false);
    let env = sky_map(64);
    let normals = [
        Vec3::Y,
        Vec3::new(0.3, 0.2, 0.9).normalize(),
        Vec3::new(-0.7, -0.1, 0.2).normalize(),
        -Vec3::Y,
    ];
    let mut errors = Vec::new();
    for level in [2, 3, 4, 5, 6] {
        let set = VplSet::from_envmap(&scene, &env, level).unwrap();
        assert_eq!(set.len(), 1 << (2 * level));
        assert!(set
            .vpls
            .iter()
            .all(|v| v.kind == VplKind::Env && v.bounce == 0));
        // Every texel's light carries Σ L ω: the set's total is the map's power.
        let total: DVec3 =
            set.vpls.iter().map(|v| v.flux.as_dvec3()).sum::<DVec3>() / set.disk_area as f64;
        let want = DVec3::from_array(env.total_power());
        assert!(
            ((total - want).abs() / want).max_element() < 1e-4,
            "{total} vs {want}"
        );
        let mut worst = 0.0f64;
        for n in normals {
            // Irradiance through eq. 6.1's term at a white Lambert receiver (f = 1/π).
            let r = receiver(&scene, Vec3::new(0.0, 0.5, 0.0), n);
            let got: DVec3 = set
                .vpls
                .iter()
                .filter_map(|v| v.connect(&r, None, set.disk_area))
                .map(|c| c.value.as_dvec3() * std::f64::consts::PI)
                .sum();
            let want = cosine_integral(&env, n);
            worst = worst.max(((got - want).abs() / want).max_element());
        }
        errors.push(worst);
    }
    // Level 4's 256 lights hold the integral within 2 %, level 6's (the map's own texels)
    // within 1 % (what is left is the map's texels cut by the receiver's horizon), and the
    // error falls with the level (measured: 24 %, 6 %, 1.7 %, 0.58 %, 0.60 %).
    assert!(errors[2] < 0.02, "{errors:?}");
    assert!(errors[4] < 0.01, "{errors:?}");
    assert!(
        errors.windows(2).take(3).all(|e| e[0] > 2.5 * e[1]),
        "{errors:?}"
    );
}

#[test]
fn the_sun_of_a_coarse_texel_keeps_its_direction() {
    let scene = lit_plane(false);
    let env = sky_map(64);
    let set = VplSet::from_envmap(&scene, &env, 2).unwrap();
    let brightest = set
        .vpls
        .iter()
        .max_by(|a, b| luminance(a.flux).total_cmp(&luminance(b.flux)))
        .unwrap();
    let sun = Vec3::new(0.4, 0.6, -0.3).normalize();
    // A level-2 texel spans ~60°: its light points within a few degrees of the sun.
    assert!(brightest.normal.dot(sun) > 0.99, "{}", brightest.normal);
}

#[test]
fn directional_lights_give_their_irradiance() {
    let scene = lit_plane(false);
    let set = VplSet::from_directions(
        &scene,
        &[[0.0, 2.0, 0.0], [1.0, 1.0, 0.0]],
        &[[3.0, 2.0, 1.0], [1.0, 1.0, 1.0]],
    )
    .unwrap();
    let r = receiver(&scene, Vec3::new(0.0, 0.5, 0.0), Vec3::Y);
    let e: DVec3 = set
        .vpls
        .iter()
        .filter_map(|v| v.connect(&r, None, set.disk_area))
        .map(|c| c.value.as_dvec3() * std::f64::consts::PI)
        .sum();
    let want = DVec3::new(3.0, 2.0, 1.0) + DVec3::ONE * std::f64::consts::FRAC_1_SQRT_2;
    assert!((e - want).abs().max_element() < 1e-5, "{e} vs {want}");
    assert!(set.vpls.iter().all(|v| v.light == u32::MAX));
    // Bad input is named.
    let e = |d: &[[f32; 3]], i: &[[f32; 3]]| {
        VplSet::from_directions(&scene, d, i)
            .unwrap_err()
            .to_string()
    };
    assert!(e(&[], &[]).contains("directions"));
    assert!(e(&[[0.0; 3]], &[[1.0; 3]]).contains("directions"));
    assert!(e(&[[f32::NAN, 1.0, 0.0]], &[[1.0; 3]]).contains("directions"));
    assert!(e(&[[0.0, 1.0, 0.0]], &[[-1.0, 1.0, 1.0]]).contains("irradiance"));
    assert!(e(&[[0.0, 1.0, 0.0]], &[]).contains("irradiance"));
    assert!(VplSet::from_envmap(&scene, &sky_map(64), 7)
        .unwrap_err()
        .to_string()
        .contains("level"));
}

/// The direct irradiance of the scene's only area light at `r` by brute force: a
/// 400 x 400 midpoint grid over the quad (unoccluded: nothing lies between them).
fn area_irradiance(scene: &Scene, r: &Receiver) -> DVec3 {
    let light = &scene.area_lights()[0];
    let [a, b, _] = light.triangles()[0];
    let c = light.triangles()[1][2];
    let (eu, ev) = (b - a, c - a);
    let n = light.normal(0);
    let m = 400;
    let da = (eu.cross(ev).length() as f64) / (m * m) as f64;
    let mut e = DVec3::ZERO;
    for i in 0..m {
        for j in 0..m {
            let y = a + eu * ((i as f32 + 0.5) / m as f32) + ev * ((j as f32 + 0.5) / m as f32);
            let d = (y - r.sp.origin).as_dvec3();
            let d2 = d.length_squared();
            let cx = r.sp.normal.as_dvec3().dot(d) / d2.sqrt();
            let cy = -n.as_dvec3().dot(d) / d2.sqrt();
            if cx > 0.0 && cy > 0.0 {
                e += light.radiance().as_dvec3() * (cx * cy / d2 * da);
            }
        }
    }
    e
}

#[test]
fn area_lights_fixed_points_and_fresh_samples_estimate_the_lights_term() {
    let scene = lit_plane(true);
    let set = VplSet::from_area_lights(&scene, 64).unwrap();
    assert_eq!(set.len(), 1);
    let v = set.vpls[0];
    assert_eq!(
        (v.kind, v.light, v.bounce),
        (VplKind::Area { points: 64 }, 1, 0)
    );
    let power = DVec3::from_array(scene.area_lights()[0].power());
    assert!((v.flux.as_dvec3() - power).abs().max_element() < 1e-4 * power.max_element());
    assert!((v.position - Vec3::new(0.5, 1.0, 0.0)).length() < 1e-5);
    assert!((v.normal - -Vec3::Y).length() < 1e-5);
    // The fixed points: K of them, equal shares summing to the light's area.
    let mut n = 0;
    let mut area = 0.0f64;
    area_points(&scene.area_lights()[0], 64, |q| {
        n += 1;
        area += (q.value.x / 2.0) as f64;
        assert!((q.position.y - 1.0).abs() < 1e-6 && (0.2..=0.8).contains(&q.position.x));
    });
    assert_eq!(n, 64);
    assert!((area - 0.36).abs() < 1e-5, "{area}");
    for (p, nrm) in [
        (Vec3::new(0.0, 0.1, 0.0), Vec3::Y),
        (
            Vec3::new(-0.8, 0.2, 0.5),
            Vec3::new(0.5, 1.0, 0.0).normalize(),
        ),
    ] {
        let r = receiver(&scene, p, nrm);
        let want = area_irradiance(&scene, &r) / std::f64::consts::PI; // times f = 1/π
                                                                       // The quadrature over 64 stratified points: within a few per cent.
        let u = v.unoccluded(&scene, &r, None, set.disk_area).as_dvec3();
        assert!(
            ((u - want).abs() / want).max_element() < 0.03,
            "{u} vs {want}"
        );
        // Fresh points by area: unbiased, within 4 SE of the brute force.
        let (mut s, mut s2, m) = (DVec3::ZERO, DVec3::ZERO, 20_000);
        for i in 0..m {
            let rng = SampleRng::new(9, i, 0);
            let c = v
                .sample_area(&scene, &r, None, [rng.get(0), rng.get(1), rng.get(2)])
                .map_or(DVec3::ZERO, |c| c.value.as_dvec3());
            s += c;
            s2 += c * c;
        }
        let mean = s / m as f64;
        let se = ((s2 / m as f64 - mean * mean) / (m - 1) as f64)
            .max(DVec3::ZERO)
            .map(f64::sqrt);
        for c in 0..3 {
            assert!(
                (mean[c] - want[c]).abs() < 4.0 * se[c],
                "{mean} vs {want} (SE {se})"
            );
        }
        assert!(se.max_element() < 0.05 * want.max_element());
    }
    // Behind the light's plane nothing; with the receiver's horizon cutting the light so
    // that no fixed point is above it, the floor keeps the value positive.
    let above = receiver(&scene, Vec3::new(0.5, 1.5, 0.0), Vec3::Y);
    assert_eq!(
        v.unoccluded(&scene, &above, None, set.disk_area),
        Vec3::ZERO
    );
    let grazing = receiver(&scene, Vec3::new(0.79999, 0.5, 0.0), Vec3::X);
    assert!(luminance(v.unoccluded(&scene, &grazing, None, set.disk_area)) > 0.0);
    // Bad input.
    let e = |s: &Scene, k| VplSet::from_area_lights(s, k).unwrap_err().to_string();
    assert!(e(&scene, 0).starts_with("points"));
    assert!(e(&lit_plane(false), 4).starts_with("scene"));
}

#[test]
fn concatenation_rescales_directions_and_checks_the_scene() {
    let scene = lit_plane(true);
    let a = VplSet::from_area_lights(&scene, 4).unwrap();
    let mut b = VplSet::from_directions(&scene, &[[0.0, 1.0, 0.0]], &[[1.0; 3]]).unwrap();
    b.stats.paths = 3;
    // A set whose disk differs (as from a looser bound) keeps its irradiance.
    b.disk_area *= 2.0;
    b.vpls[0].flux *= 2.0;
    let mut c = VplSet::from_directions(&scene, &[[1.0, 0.0, 0.0]], &[[2.0; 3]]).unwrap();
    c.stats.paths = 4;
    let bc = (&b + &c).unwrap();
    assert_eq!(bc.len(), 2);
    assert_eq!(bc.disk_area, b.disk_area);
    assert_eq!(bc.stats.paths, 7);
    let e = |v: &Vpl, set: &VplSet| v.flux / set.disk_area;
    assert!((e(&bc.vpls[0], &bc) - Vec3::ONE).abs().max_element() < 1e-6);
    assert!((e(&bc.vpls[1], &bc) - Vec3::splat(2.0)).abs().max_element() < 1e-6);
    // Without directions of its own a set takes the other's disk.
    let abc = a.concat(&bc).unwrap();
    assert_eq!(abc.disk_area, bc.disk_area);
    assert_eq!(abc.vpls[0], a.vpls[0]);
    assert!(abc.vpls[0].kind.is_area());
    let other = lit_plane(false);
    let d = VplSet::from_directions(&other, &[[0.0, 1.0, 0.0]], &[[1.0; 3]]).unwrap();
    assert!(a.concat(&d).unwrap_err().to_string().starts_with("other"));
}

#[test]
fn view_share_counts_the_lights_the_view_sees() {
    let scene = lit_plane(true);
    let cam = Camera::look_at(Vec3::new(0.0, 3.0, 0.1), Vec3::ZERO, Vec3::Y, 50.0, 16, 12).unwrap();
    // Lights from above reach the plane; from below, never; the area light does.
    let mut set = VplSet::from_directions(
        &scene,
        &[[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.2, 1.0, 0.0]],
        &[[1.0; 3]; 3],
    )
    .unwrap();
    set = set
        .concat(&VplSet::from_area_lights(&scene, 8).unwrap())
        .unwrap();
    let s = set.view_share(&scene, &cam, 16, Some(2)).unwrap();
    assert_eq!((s.contributing, s.total), (3, 4));
    assert!(s.points > 0 && (s.fraction() - 0.75).abs() < 1e-12);
    assert_eq!(s.by_kind, [(0, 0), (2, 3), (0, 0), (1, 1)]);
    assert_eq!(s, set.view_share(&scene, &cam, 16, Some(1)).unwrap());
    let other = lit_plane(false);
    assert!(set
        .view_share(&other, &cam, 16, None)
        .unwrap_err()
        .to_string()
        .starts_with("vpls"));
}
