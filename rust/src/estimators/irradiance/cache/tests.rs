//! The cache's weights, interpolation and clamping on hand-made records (no rays), its
//! parameters' checks and its file format.

use std::path::Path;

use glam::Vec3;

use super::*;

fn record(position: Vec3, normal: Vec3, e: f32, radius: f32) -> IrradianceRecord {
    IrradianceRecord {
        position,
        normal,
        irradiance: [e, 2.0 * e, 3.0 * e],
        radius,
        ..IrradianceRecord::default()
    }
}

fn state(params: IrradianceParams) -> IrradianceState {
    IrradianceState::new(&params)
}

const Z: Vec3 = Vec3::Z;

#[test]
fn the_weight_is_zero_on_the_border_and_positive_inside() {
    let s = state(IrradianceParams::DEFAULT);
    let r = record(Vec3::ZERO, Z, 1.0, 1.0);
    // a = 0.2, R = 1: the border is 0.2 away in the plane.
    assert_eq!(s.weight(&r, Vec3::new(0.2, 0.0, 0.0), Z), None);
    assert_eq!(s.weight(&r, Vec3::new(0.0, -0.25, 0.0), Z), None);
    let w = s.weight(&r, Vec3::new(0.199, 0.0, 0.0), Z).unwrap();
    assert!(w > 0.0 && w < 0.1, "{w}");
    // Eq. 3.7 inside: 1/e − 1/a.
    let w = s.weight(&r, Vec3::new(0.1, 0.0, 0.0), Z).unwrap();
    assert!((w - (1.0 / 0.1 - 1.0 / 0.2)).abs() < 1e-5, "{w}");
    // The normal term alone: a normal turned so that sqrt(1 − cos) = a is on the border.
    let border = (1.0 - 0.2f32 * 0.2).acos();
    let tilted = |angle: f32| Vec3::new(angle.sin(), 0.0, angle.cos());
    assert_eq!(s.weight(&r, Vec3::ZERO, tilted(border * 1.001)), None);
    assert!(s.weight(&r, Vec3::ZERO, tilted(border * 0.99)).unwrap() > 0.0);
    assert_eq!(s.weight(&r, Vec3::ZERO, -Z), None);
}

#[test]
fn a_records_own_point_gets_its_irradiance_exactly() {
    let mut s = state(IrradianceParams::DEFAULT);
    let a = record(Vec3::ZERO, Z, 0.3, 1.0);
    let mut b = record(Vec3::new(0.05, 0.0, 0.0), Z, 7.0, 1.0);
    b.translation = [Vec3::X; 3];
    s.push(a, false).unwrap();
    s.push(b, false).unwrap();
    let mut scratch = Vec::new();
    let at_a = s.interpolate(Vec3::ZERO, Z, &mut scratch).unwrap();
    assert_eq!(at_a.irradiance, a.irradiance);
    assert_eq!(at_a.weight_sum, f64::INFINITY);
    assert_eq!(at_a.records, 2);
    let at_b = s.interpolate(b.position, Z, &mut scratch).unwrap();
    assert_eq!(at_b.irradiance, b.irradiance);
}

#[test]
fn a_record_in_front_is_never_used() {
    let mut s = state(IrradianceParams::DEFAULT);
    // 5 cm above the point's plane, 5 cm aside: within reach (e ≈ 0.07 < 0.2), in front
    // by more than 5% of its reach.
    s.push(record(Vec3::new(0.05, 0.0, 0.05), Z, 1.0, 1.0), false)
        .unwrap();
    let mut scratch = Vec::new();
    assert!(s.interpolate(Vec3::ZERO, Z, &mut scratch).is_none());
    assert!(!s.covers(Vec3::ZERO, Z, &mut scratch));
    // The same record behind the point's plane serves it.
    let mut s = state(IrradianceParams::DEFAULT);
    s.push(record(Vec3::new(0.05, 0.0, -0.05), Z, 1.0, 1.0), false)
        .unwrap();
    assert!(s.interpolate(Vec3::ZERO, Z, &mut scratch).is_some());
}

#[test]
fn gradients_move_the_records_irradiance_as_eq_3_8_says() {
    let mut r = record(Vec3::ZERO, Z, 1.0, 1.0);
    r.translation = [Vec3::new(2.0, 0.0, 0.0); 3];
    r.rotation = [Vec3::new(0.0, 3.0, 0.0); 3];
    let x = Vec3::new(0.05, 0.0, 0.0);
    // Tilted about y by 0.05 rad: n_i × n = (0, sin, 0).
    let n = Vec3::new(0.05f32.sin(), 0.0, 0.05f32.cos());
    let turn = Z.cross(n).y as f64 * 3.0;
    for (gradients, extra) in [
        (Gradients::None, 0.0),
        (Gradients::Rotation, turn),
        (Gradients::Both, turn + 0.1),
    ] {
        let mut s = state(IrradianceParams {
            gradients,
            ..IrradianceParams::DEFAULT
        });
        s.push(r, false).unwrap();
        let got = s.interpolate(x, n, &mut Vec::new()).unwrap();
        for c in 0..3 {
            let want = r.irradiance[c] as f64 + extra;
            assert!(
                (got.irradiance[c] as f64 - want).abs() < 1e-5,
                "{gradients:?} channel {c}: {} vs {want}",
                got.irradiance[c]
            );
        }
    }
}

#[test]
fn channels_pushed_below_zero_are_clamped_and_counted() {
    let mut r = record(Vec3::ZERO, Z, 0.01, 1.0);
    r.translation = [Vec3::new(-1.0, 0.0, 0.0); 3];
    let mut s = state(IrradianceParams::DEFAULT);
    s.push(r, false).unwrap();
    // E − 0.1 per channel: 0.01, 0.02, 0.03 all go below 0.
    let got = s
        .interpolate(Vec3::new(0.1, 0.0, 0.0), Z, &mut Vec::new())
        .unwrap();
    assert_eq!(got.irradiance, [0.0; 3]);
    assert_eq!(got.clamped, 3);
}

#[test]
fn the_mean_is_weighted_by_eq_3_7() {
    let mut s = state(IrradianceParams::DEFAULT);
    s.push(record(Vec3::new(-0.1, 0.0, 0.0), Z, 1.0, 1.0), false)
        .unwrap();
    s.push(record(Vec3::new(0.05, 0.0, 0.0), Z, 4.0, 1.0), false)
        .unwrap();
    let got = s.interpolate(Vec3::ZERO, Z, &mut Vec::new()).unwrap();
    let (w1, w2) = (1.0 / 0.1 - 5.0, 1.0 / 0.05 - 5.0);
    let want = (w1 * 1.0 + w2 * 4.0) / (w1 + w2);
    assert!((got.irradiance[0] as f64 - want).abs() < 1e-5);
    assert!((got.weight_sum - (w1 + w2)).abs() < 1e-4);
    assert_eq!(got.records, 2);
}

#[test]
fn neighbour_clamping_bounds_both_radii() {
    let mut s = state(IrradianceParams::DEFAULT);
    s.push(record(Vec3::ZERO, Z, 1.0, 10.0), true).unwrap();
    // 1 away with R = 0.1: the old record's R drops to 0.1 + 1; the new one keeps 0.1.
    s.push(record(Vec3::X, Z, 1.0, 0.1), true).unwrap();
    assert!((s.records()[0].radius - 1.1).abs() < 1e-6);
    assert_eq!(s.records()[1].radius, 0.1);
    // A large record next to a small one is bounded by it (R ≤ 1.1 + 0.5).
    s.push(record(Vec3::new(0.5, 0.0, 0.0), Z, 1.0, 50.0), true)
        .unwrap();
    assert!(
        (s.records()[2].radius - 0.6).abs() < 1e-6,
        "{}",
        s.records()[2].radius
    );
    assert_eq!(s.counters().clamped_radii, 2);
    // Without clamping nothing changes.
    let mut s = state(IrradianceParams::DEFAULT);
    s.push(record(Vec3::ZERO, Z, 1.0, 10.0), false).unwrap();
    s.push(record(Vec3::X, Z, 1.0, 0.1), false).unwrap();
    assert_eq!(s.records()[0].radius, 10.0);
}

#[test]
fn bad_parameters_are_named() {
    let bad = |p: IrradianceParams| match IrradianceCache::new(p) {
        Err(Error::InvalidArgument { name, .. }) => name,
        other => panic!("{other:?}"),
    };
    let d = IrradianceParams::DEFAULT;
    assert_eq!(bad(IrradianceParams { a: 0.0, ..d }), "a");
    assert_eq!(bad(IrradianceParams { a: -1.0, ..d }), "a");
    assert_eq!(bad(IrradianceParams { a: f32::NAN, ..d }), "a");
    assert_eq!(bad(IrradianceParams { a: 1.5, ..d }), "a");
    assert_eq!(
        bad(IrradianceParams {
            strata: (0, 4),
            ..d
        }),
        "strata"
    );
    assert_eq!(
        bad(IrradianceParams {
            strata: (4, 0),
            ..d
        }),
        "strata"
    );
    assert_eq!(
        bad(IrradianceParams {
            strata: (1 << 9, 1 << 9),
            ..d
        }),
        "strata"
    );
    assert_eq!(bad(IrradianceParams { r_min: 0.0, ..d }), "r_min");
    assert_eq!(
        bad(IrradianceParams {
            r_min: 3.0,
            r_max: 2.0,
            ..d
        }),
        "r_max"
    );
    assert_eq!(
        bad(IrradianceParams {
            r_max: f32::INFINITY,
            ..d
        }),
        "r_max"
    );
    assert_eq!(
        bad(IrradianceParams {
            secondary_spp: 0,
            ..d
        }),
        "secondary_spp"
    );
    assert!(matches!(
        Gradients::parse("some"),
        Err(Error::InvalidArgument { name, .. }) if name == "gradients"
    ));
    assert_eq!(Gradients::parse("rotation").unwrap(), Gradients::Rotation);
}

fn filled() -> IrradianceCache {
    let cache = IrradianceCache::new(IrradianceParams {
        gradients: Gradients::Rotation,
        ..IrradianceParams::DEFAULT
    })
    .unwrap();
    {
        let mut s = cache.write();
        for i in 0..50 {
            let mut r = record(
                Vec3::new(i as f32 * 0.3, 1.0, -2.0),
                Z,
                i as f32,
                0.5 + i as f32,
            );
            r.rotation = [Vec3::new(0.1 * i as f32, -1.0, 0.0); 3];
            r.translation = [Vec3::new(0.0, 0.5, 0.0); 3];
            s.push(r, true).unwrap();
        }
        s.scene = Some(0x1234);
        s.default_footprint = Some(0.01);
    }
    cache
}

#[test]
fn files_round_trip_and_refuse_corruption() {
    let cache = filled();
    let bytes = cache.to_bytes();
    let back = IrradianceCache::from_bytes(&bytes, Path::new("c.irr")).unwrap();
    assert_eq!(back.params(), cache.params());
    assert_eq!(back.read().records(), cache.read().records());
    assert_eq!(back.scene_fingerprint(), Some(0x1234));
    assert_eq!(back.default_footprint(), Some(0.01));
    assert_eq!(back.to_bytes(), bytes);
    // The same answers from the loaded index.
    let (x, n) = (Vec3::new(1.0, 1.0, -2.0), Z);
    let (a, b) = (cache.read(), back.read());
    assert_eq!(
        a.interpolate(x, n, &mut Vec::new()),
        b.interpolate(x, n, &mut Vec::new())
    );
    let parse = |bytes: &[u8]| match IrradianceCache::from_bytes(bytes, Path::new("c.irr")) {
        Err(Error::Parse { path, reason }) => {
            assert_eq!(path, Path::new("c.irr"));
            reason
        }
        other => panic!("{other:?}"),
    };
    assert!(parse(&bytes[..bytes.len() - 1]).contains("bytes"));
    assert!(parse(&bytes[..20]).contains("truncated"));
    assert!(parse(b"VISCACHE").contains("magic"));
    let mut flipped = bytes.clone();
    flipped[100] ^= 1;
    assert!(parse(&flipped).contains("checksum"));
    // A record made invalid with a checksum to match: named by its index.
    let mut bad = bytes[..bytes.len() - 8].to_vec();
    let at = 8 + 4 + 32 + 8 + 4 + 8 + 3 * 112 + 36; // record 3's radius
    bad[at..at + 4].copy_from_slice(&(-1.0f32).to_le_bytes());
    let sum = crate::estimators::irradiance::io::checksum(&bad);
    bad.extend(sum.to_le_bytes());
    assert!(parse(&bad).contains("record 3"), "{}", parse(&bad));
}

#[test]
fn records_never_serve_across_a_floor_wall_edge() {
    // A floor record 1 mm from the wall's foot, however large its radius and `a`: a wall
    // point at the foot differs by 90° in normal, which eq. 3.7's normal term alone puts
    // at the border for a = 1.
    for a in [0.05f32, 0.2, 1.0] {
        let mut s = state(IrradianceParams {
            a,
            ..IrradianceParams::DEFAULT
        });
        s.push(
            record(Vec3::new(-0.001, 0.0, 0.0), Vec3::Y, 1.0, 100.0),
            true,
        )
        .unwrap();
        let mut scratch = Vec::new();
        for y in [0.0f32, 1e-4, 0.01] {
            let wall = Vec3::new(0.0, y, 0.0);
            assert!(
                s.interpolate(wall, -Vec3::X, &mut scratch).is_none(),
                "a {a} y {y}"
            );
        }
        // A grazing pair of normals 1° apart is served.
        let tilt = 1f32.to_radians();
        let n = Vec3::new(tilt.sin(), tilt.cos(), 0.0);
        assert!(
            s.interpolate(Vec3::ZERO, n, &mut scratch).is_some(),
            "a {a}"
        );
    }
}
