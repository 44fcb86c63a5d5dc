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
