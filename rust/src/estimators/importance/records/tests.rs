//! The records: B bounds U over each record's region, F never exceeds U, rows of every
//! light kind, the lookup against a brute-force scan of eq. 6.3, the α-max weights'
//! partition at random points, the build's determinism over threads, extremes and bad
//! parameters.

use std::time::Instant;

use glam::Vec3;

use super::*;
use crate::camera::{Camera, GBuffer};
use crate::error::Error;
use crate::estimators::importance::bound::Region;
use crate::estimators::importance::combine::{Combine, ROWS};
use crate::geometry::Scene;
use crate::lights::vpl::TraceParams;
use crate::sampling::rng::{hash4, to_unit_f64};

fn setup() -> crate::scenes::Setup {
    crate::scenes::load("cornell", 0.25, 0).unwrap()
}

fn lights(s: &crate::scenes::Setup, count: u64) -> VplSet {
    let cam = s.camera.with_resolution(16, 12).unwrap();
    let p = TraceParams {
        count,
        depth: 1,
        seed: 3,
        importance: None,
        lights: true,
    };
    VplSet::trace(&s.scene, &s.envmap, Some(&cam), &p, Some(2)).unwrap()
}

fn built(
    s: &crate::scenes::Setup,
    set: &VplSet,
    camera: &Camera,
    params: ImportanceParams,
    threads: usize,
) -> ImportanceCache {
    let cache = ImportanceCache::new(set, params).unwrap();
    let g = GBuffer::render(&s.scene, camera, 0, false, Some(threads)).unwrap();
    let report = cache
        .build_from(
            &s.scene,
            &g,
            Some(threads),
            Instant::now(),
            None,
            &mut |_, _| true,
        )
        .unwrap();
    assert!(report.complete && report.records == cache.len());
    assert!(report.grid > 0 && report.inserted >= report.grid);
    assert_eq!(
        report.pairs,
        (report.inserted + report.discarded) as u64 * set.vpls.len() as u64
    );
    cache
}

fn unit(seed: u64, i: u64, d: u64) -> f32 {
    to_unit_f64(hash4(seed, i, 0, d)) as f32
}

/// A point of `region`'s ball and a unit normal within its cone.
fn point_in(region: &Region, seed: u64, i: u64) -> (Vec3, Vec3) {
    let r = region.radius * unit(seed, i, 0).cbrt();
    let dir = loop_dir(seed, i);
    let x = region.position + dir * r;
    // A normal within the cone: tilt the record's by up to the cone's angle.
    let t = unit(seed, i, 4) * region.cone;
    let side = region.normal.any_orthonormal_vector();
    let side = glam::Quat::from_axis_angle(region.normal, unit(seed, i, 5) * std::f32::consts::TAU)
        .mul_vec3(side);
    let n = (region.normal * t.cos() + side * t.sin()).normalize();
    (x, n)
}

fn loop_dir(seed: u64, i: u64) -> Vec3 {
    let z = 2.0 * unit(seed, i, 1) - 1.0;
    let phi = unit(seed, i, 2) * std::f32::consts::TAU;
    let s = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(s * phi.cos(), s * phi.sin(), z)
}

/// `L f_s G` of light `v` at `x` (normal `n`) with the diffuse `f_s`, unoccluded.
fn u_at(scene: &Scene, v: &Vpl, x: Vec3, n: Vec3, albedo: [f32; 3], disk_area: f32) -> f64 {
    let sp = crate::estimators::direct::ShadingPoint {
        origin: x,
        normal: n,
        wo: n,
        material: crate::bsdf::Material::Lambert { albedo },
    };
    let r = crate::estimators::many_lights::light_paths::Receiver::new(scene, sp);
    v.connect(&r, None, disk_area)
        .map_or(0.0, |c| luminance(c.value) as f64)
}

/// B bounds U at 2000 random points of every record's region (lights outside the ball:
/// within it `G_max` is unbounded and capped, module docs), F never exceeds U, B never
/// below U at the record; for surface and emitter VPLs.
#[test]
fn b_bounds_u_over_the_region_and_f_stays_below_u() {
    let s = setup();
    let set = lights(&s, 150);
    let cam = s.camera.with_resolution(24, 18).unwrap();
    let params = ImportanceParams {
        spacing: 6,
        ..ImportanceParams::DEFAULT
    };
    let cache = built(&s, &set, &cam, params, 2);
    let n = set.vpls.len();
    let state = cache.read();
    let records = &state.index.records().records;
    assert!(records.len() >= 12, "{}", records.len());
    let albedo_of = |x: Vec3, nrm: Vec3| {
        // The record's material: its object's, found by a ray into the surface.
        let h = s
            .scene
            .intersect1(x + nrm * 1e-3, -nrm, 1.0, &mut Default::default())
            .unwrap();
        crate::estimators::irradiance::build::diffuse_albedo(
            &s.scene.mesh().objects[h.obj as usize].material,
        )
    };
    let (mut checked, mut behind) = (0u64, 0u64);
    for (ri, rec) in records.iter().enumerate() {
        let albedo = albedo_of(rec.position, rec.normal);
        let f_s = Vec3::from(albedo) * std::f32::consts::FRAC_1_PI;
        let region = Region {
            position: rec.position,
            normal: rec.normal,
            radius: rec.radius,
            cone: REGION_CONE,
        };
        for k in 0..n {
            let (f, u) = (rec.value(Row::F, k), rec.value(Row::U, k));
            let total_u = rec.row(Row::U).total();
            assert!(
                f <= u + total_u * 1e-6,
                "record {ri} light {k}: F {f} > U {u}"
            );
        }
        for (k, v) in set.vpls.iter().enumerate() {
            if v.position.distance(rec.position) <= rec.radius * 1.001 {
                continue;
            }
            let u0 = u_at(&s.scene, v, rec.position, rec.normal, albedo, set.disk_area);
            let b = b_value(v, &region, f_s, set.disk_area, u0);
            if u0 == 0.0 && b > 0.0 {
                behind += 1;
            }
            for i in 0..2000 / n as u64 + 1 {
                let (x, nx) = point_in(&region, ri as u64 * 7919 + k as u64, i);
                let u = u_at(&s.scene, v, x, nx, albedo, set.disk_area);
                assert!(
                    b >= u * (1.0 - 1e-4),
                    "record {ri} light {k} ({:?}): B {b} < U {u} at {x}",
                    v.kind
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 10_000, "{checked}");
    // Row B keeps lights the record's own point cannot see (Fig. 6.5b).
    assert!(behind > 0);
}

/// The lookup is eq. 6.3's `nearest` by a linear scan (records within the largest reach
/// and the cone), at random points near the records.
#[test]
fn lookup_is_eq_6_3_by_brute_force() {
    let s = setup();
    let set = lights(&s, 40);
    let cam = s.camera.with_resolution(32, 24).unwrap();
    let cache = built(&s, &set, &cam, ImportanceParams::DEFAULT, 2);
    let state = cache.read();
    let records = &state.index.records().records;
    for lam in [0.0f32, 0.5, 4.0] {
        let lambda = ImportanceCache::lambda_world(&state, lam);
        for i in 0..300u64 {
            let base = &records[i as usize % records.len()];
            let x = base.position + loop_dir(11, i) * base.radius * unit(11, i, 3);
            let nrm = (base.normal + loop_dir(12, i) * 0.5).normalize();
            let got = state.nearest(x, nrm, 3, lambda);
            let mut all: Vec<(f32, u32)> = records
                .iter()
                .enumerate()
                .filter(|(_, r)| {
                    r.position.distance_squared(x) <= state.max_radius * state.max_radius
                        && crate::spatial::weight::normal_angle(
                            r.normal.cross(nrm).length(),
                            r.normal.dot(nrm),
                        ) < REGION_CONE
                })
                .map(|(id, r)| {
                    let key =
                        Metric::DistanceNormal { lambda }.between(x, nrm, r.position, r.normal);
                    (key, id as u32)
                })
                .collect();
            all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            // Ties within rounding may swap: compare the keys kept.
            let want: Vec<f32> = all.iter().take(3).map(|p| p.0).collect();
            let mut keys: Vec<f32> = got
                .ids()
                .iter()
                .map(|&id| {
                    let r = &records[id as usize];
                    Metric::DistanceNormal { lambda }.between(x, nrm, r.position, r.normal)
                })
                .collect();
            keys.sort_by(f32::total_cmp);
            assert_eq!(keys.len(), want.len(), "lam {lam} point {i}");
            for (a, b) in keys.iter().zip(&want) {
                assert!(
                    (a - b).abs() <= 1e-4 * (1.0 + b.abs()),
                    "lam {lam} point {i}: {keys:?} vs {want:?}"
                );
            }
        }
    }
}

/// At random shading points, α-max's weights partition the lights (sum 1 per light for
/// several α), balance's too, and each light has a positive pmf in some row.
#[test]
fn weights_partition_every_light() {
    let s = setup();
    let set = lights(&s, 60);
    let cam = s.camera.with_resolution(24, 18).unwrap();
    let cache = built(&s, &set, &cam, ImportanceParams::DEFAULT, 1);
    let state = cache.read();
    let n = set.vpls.len();
    let records = &state.index.records().records;
    let lambda = ImportanceCache::lambda_world(&state, 1.0);
    for i in 0..50u64 {
        let base = &records[i as usize % records.len()];
        let x = base.position + loop_dir(5, i) * base.radius * 0.5;
        let near = state.nearest(x, base.normal, 3, lambda);
        assert!(near.len >= 1);
        let m = state.matrix(near.ids(), n).unwrap();
        for alpha in [[1.0; ROWS], [0.5, 0.5, 0.5, 1.0], [0.1, 0.9, 0.3, 0.7]] {
            for combine in [Combine::AlphaMax(alpha), Combine::Balance] {
                for k in 0..n {
                    let sum: f64 = Row::ALL.iter().map(|&r| m.weight(&combine, r, k)).sum();
                    assert!((sum - 1.0).abs() < 1e-12, "{combine:?} light {k}: {sum}");
                }
            }
        }
    }
}

/// Chi-square of the lights drawn from each row of real lookups (records of a built
/// cache, sparse rows among them) against the row's mean pmf `p̄`.
#[test]
fn draws_from_built_records_follow_the_mean_pmf() {
    let s = setup();
    let set = lights(&s, 60);
    let cam = s.camera.with_resolution(24, 18).unwrap();
    let cache = built(&s, &set, &cam, ImportanceParams::DEFAULT, 2);
    let state = cache.read();
    let n = set.vpls.len();
    let records = &state.index.records().records;
    assert!(records.iter().any(|r| r
        .rows
        .iter()
        .any(|row| matches!(row, RowCdf::Sparse { .. }))));
    let lambda = ImportanceCache::lambda_world(&state, 1.0);
    for i in 0..4u64 {
        let base = &records[(7 * i as usize) % records.len()];
        let x = base.position + loop_dir(9, i) * base.radius * 0.5;
        let near = state.nearest(x, base.normal, 3, lambda);
        let m = state.matrix(near.ids(), n).unwrap();
        for row in Row::ALL {
            if m.records(row) == 0 {
                continue;
            }
            let draws = 200_000u64;
            let mut count = vec![0u64; n];
            for j in 0..draws {
                let u = |d| to_unit_f64(hash4(i, j, d, row as u64));
                let k = m.draw(row, u(0), u(1)).unwrap();
                count[k] += 1;
            }
            let (mut chi2, mut bins, mut outside) = (0.0, 0, 0);
            for (k, &c) in count.iter().enumerate() {
                let e = m.pmf(row, k) * draws as f64;
                if e > 0.0 {
                    chi2 += (c as f64 - e).powi(2) / e;
                    bins += 1;
                } else {
                    outside += c;
                }
            }
            assert_eq!(outside, 0, "{row:?}: draws of zero-mass lights");
            let dof = (bins - 1) as f64;
            assert!(
                chi2 < dof + 5.0 * (2.0 * dof).sqrt(),
                "{row:?} at {i}: {chi2} on {dof}"
            );
        }
    }
}

/// The same records, bit for bit, on 1 and 2 threads; a second build of the same view adds
/// no grid record.
#[test]
fn build_is_the_same_on_any_thread_count() {
    let s = setup();
    let set = lights(&s, 50);
    let cam = s.camera.with_resolution(32, 24).unwrap();
    let a = built(&s, &set, &cam, ImportanceParams::DEFAULT, 1);
    let b = built(&s, &set, &cam, ImportanceParams::DEFAULT, 2);
    {
        let (ra, rb) = (a.read(), b.read());
        assert_eq!(ra.index.records().records, rb.index.records().records);
    }
    let g = GBuffer::render(&s.scene, &cam, 0, false, Some(2)).unwrap();
    let again = a
        .build_from(&s.scene, &g, Some(2), Instant::now(), None, &mut |_, _| {
            true
        })
        .unwrap();
    assert_eq!(again.inserted, 0);
    // Rows take at most 12 bytes per light and record; sparse ones less.
    let state = a.read();
    let records = &state.index.records().records;
    let rows: usize = records
        .iter()
        .flat_map(|r| r.rows.iter().map(RowCdf::bytes))
        .sum();
    assert!(rows <= a.len() * set.vpls.len() * 12);
    assert!(records
        .iter()
        .any(|r| matches!(r.row(Row::F), RowCdf::Sparse { .. })));
    let overhead = a.len() * std::mem::size_of::<ImportanceRecord>() + state.index.memory_bytes();
    drop(state);
    assert_eq!(a.memory_bytes(), rows + overhead);
}

/// A row stored sparse (under half its lights of positive value) gives every light the
/// mass the dense row gives it and the draws land on the same lights; the form is chosen
/// by the count of positive values, and sparse rows take fewer bytes.
#[test]
fn sparse_and_dense_rows_are_the_same_distribution() {
    let n = 200;
    for (case, zeros) in [0.0, 0.3, 0.6, 0.95, 1.0].into_iter().enumerate() {
        let values: Vec<f64> = (0..n as u64)
            .map(|k| {
                let u = |d| to_unit_f64(hash4(case as u64, k, d, 3));
                match u(0) {
                    x if x < zeros => [0.0, -1.0, f64::NAN][k as usize % 3],
                    _ => u(1).powi(4) * 1e3,
                }
            })
            .collect();
        let row = RowCdf::from_values(&values);
        let positive = values.iter().filter(|x| **x > 0.0).count();
        assert_eq!(
            matches!(row, RowCdf::Sparse { .. }),
            2 * positive < n,
            "{zeros}"
        );
        assert!(row.bytes() <= 4 * n && row.bytes() <= 8 * positive.max(n / 2));
        let dense = row.dense(n);
        let as_dense = RowCdf::Dense(dense.clone().into_boxed_slice());
        assert_eq!(dense.len(), n);
        for (k, &x) in values.iter().enumerate() {
            assert_eq!(row.value(k), as_dense.value(k), "light {k}");
            // (A tiny value may vanish in the f32 running sum: never the reverse.)
            assert!(row.value(k) <= 0.0 || x > 0.0, "light {k}");
        }
        if positive == 0 {
            assert_eq!(row.total(), 0.0);
            continue;
        }
        let (mut a, mut b) = (
            Matrix::<f32>::new(n).unwrap(),
            Matrix::<f32>::new(n).unwrap(),
        );
        a.push_view(Row::U, row.view());
        b.push(Row::U, &dense);
        for j in 0..2000u64 {
            let u = |d| to_unit_f64(hash4(9, j, d, case as u64));
            let (ka, kb) = (a.draw(Row::U, u(0), u(1)), b.draw(Row::U, u(0), u(1)));
            assert_eq!(ka, kb);
            let k = ka.unwrap();
            assert!(values[k] > 0.0, "drew light {k} of value {}", values[k]);
            assert_eq!(a.pmf(Row::U, k), b.pmf(Row::U, k));
        }
    }
}

/// Extremes: one light; every light occluded at a record (row F empty, the others still
/// serve); a point far from every record (row C alone); a light 1e-6 from a receiver
/// (finite rows).
#[test]
fn extremes() {
    let s = setup();
    let set = lights(&s, 30);
    // One light.
    let one = VplSet {
        vpls: vec![set.vpls[5]],
        ..set.clone()
    };
    let cam = s.camera.with_resolution(16, 12).unwrap();
    let c1 = built(&s, &one, &cam, ImportanceParams::DEFAULT, 2);
    {
        let st = c1.read();
        let r = &st.index.records().records[0];
        let m = st.matrix(&[0], 1).unwrap();
        let draw = m.draw(Row::C, 0.3, 0.9);
        assert_eq!(draw, Some(0));
        assert!(r.rows.iter().all(|row| row.dense(1).len() == 1));
    }
    // Every light occluded: a record outside a closed emitting sphere, facing it, sees
    // the VPLs on its inside only through its wall.
    let sphere =
        crate::testing::furnace_sphere(3, crate::bsdf::Material::lambert([0.5; 3]).unwrap());
    let black = crate::lights::envmap::EnvMap::constant([0.0; 3], 8).unwrap();
    let tp = TraceParams {
        count: 60,
        depth: 1,
        seed: 1,
        importance: None,
        lights: true,
    };
    let inside = VplSet::trace(&sphere, &black, None, &tp, Some(2)).unwrap();
    let cache = ImportanceCache::new(&inside, ImportanceParams::DEFAULT).unwrap();
    let (rec, _) = cache
        .make_record(
            &sphere,
            (Vec3::new(0.0, 3.0, 0.0), -Vec3::Y, -Vec3::Y),
            [0.5; 3],
            0.1,
        )
        .unwrap();
    let n = inside.vpls.len();
    let f_total = rec.row(Row::F).total();
    let u_total = rec.row(Row::U).total();
    assert_eq!(f_total, 0.0);
    assert!(
        u_total > 0.0,
        "some lights face the point through the floor"
    );
    let mut m = Matrix::<f32>::new(n).unwrap();
    for row in [Row::F, Row::U, Row::B] {
        m.push_view(row, rec.row(row).view());
    }
    assert_eq!(m.records(Row::F), 0);
    assert_eq!(m.records(Row::U), 1);
    let n = set.vpls.len();
    // Far from every record: no record, row C alone.
    let c30 = built(&s, &set, &cam, ImportanceParams::DEFAULT, 2);
    let st = c30.read();
    let far = st.nearest(Vec3::splat(1e6), Vec3::Y, 3, 0.0);
    assert_eq!(far.len, 0);
    let m = st.matrix(far.ids(), n).unwrap();
    assert_eq!(m.records(Row::U), 0);
    assert_eq!(m.pmf(Row::C, 3), 1.0 / n as f64);
    // A light 1e-6 from the receiver: finite rows.
    let v = set
        .vpls
        .iter()
        .find(|v| v.kind == VplKind::Surface)
        .unwrap();
    let p = v.position + v.normal * 1e-6;
    let (rec, _) = cache
        .make_record(&s.scene, (p, v.normal, v.normal), [0.5; 3], 0.01)
        .unwrap();
    assert!(rec.rows.iter().all(RowCdf::is_finite));
}

/// Bad parameters name themselves; an empty light set names `lights`.
#[test]
fn bad_parameters_are_named() {
    let s = setup();
    let set = lights(&s, 10);
    let name = |r: Result<ImportanceCache>| match r {
        Err(Error::InvalidArgument { name, .. }) => name,
        other => panic!("{:?}", other.map(|c| c.len())),
    };
    let p = ImportanceParams::DEFAULT;
    assert_eq!(
        name(ImportanceCache::new(
            &set,
            ImportanceParams { spacing: 0, ..p }
        )),
        "spacing"
    );
    assert_eq!(
        name(ImportanceCache::new(
            &set,
            ImportanceParams { nearest: 0, ..p }
        )),
        "nearest"
    );
    assert_eq!(
        name(ImportanceCache::new(
            &set,
            ImportanceParams { lam: -1.0, ..p }
        )),
        "lam"
    );
    assert_eq!(
        name(ImportanceCache::new(
            &set,
            ImportanceParams {
                alpha: [0.5, 0.0, 1.0, 1.0],
                ..p
            }
        )),
        "alpha"
    );
    let empty = VplSet {
        vpls: Vec::new(),
        ..set.clone()
    };
    assert_eq!(name(ImportanceCache::new(&empty, p)), "lights");
    let mut c = ImportanceCache::new(&set, p).unwrap();
    assert!(c.set_alpha([2.0, 1.0, 1.0, 1.0]).is_err());
    assert_eq!(c.params().alpha, p.alpha);
    // A cache of other geometry.
    let other = crate::scenes::load("cornell", 0.25, 1).unwrap();
    let g = GBuffer::render(
        &other.scene,
        &other.camera.with_resolution(8, 6).unwrap(),
        0,
        false,
        None,
    )
    .unwrap();
    if other.scene.geometry_fingerprint() != s.scene.geometry_fingerprint() {
        let e = c
            .build_from(&other.scene, &g, None, Instant::now(), None, &mut |_, _| {
                true
            })
            .unwrap_err();
        assert!(e.to_string().starts_with("cache"), "{e}");
        assert!(c.is_empty());
    }
}
