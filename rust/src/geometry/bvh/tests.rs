use super::build::{local_scale, probe_rays};
use super::closest::ClosestRay;
#[cfg(target_arch = "x86_64")]
use super::packet::Packet;
use super::shadow::HintedRay;
use super::*;
use crate::bsdf::Material;
use crate::geometry::bvh::bvh8::{PortableBoxTest, Stack, WIDTH};
#[cfg(target_arch = "x86_64")]
use crate::geometry::bvh::watertight::{lanes, WatertightPacket};
use crate::geometry::mesh::Mesh;
use glam::{vec3a, Vec3};

/// 600 random triangles of side about 0.6 in a 4-unit cube (`seed` picks them).
fn triangle_soup(seed: u64) -> Mesh {
    use crate::sampling::rng::{hash4, to_unit_f32};
    let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, seed));
    let mut soup = Mesh::new();
    let mut v = Vec::new();
    for k in 0..600u64 {
        let c = vec3a(unit(1, k), unit(2, k), unit(3, k)) * 4.0;
        for j in 0..3u64 {
            let e = vec3a(unit(4, 3 * k + j), unit(5, 3 * k + j), unit(6, 3 * k + j));
            v.push((c + (e - 0.5) * 0.6).to_array());
        }
    }
    let faces: Vec<[i64; 3]> = (0..600).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
    soup.add_indexed(&v, &faces, Material::DEFAULT, None)
        .unwrap();
    soup
}

fn quad_mesh(scale: f32) -> Mesh {
    let mut m = Mesh::new();
    let v = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ]
    .map(|p: [f32; 3]| p.map(|c| c * scale));
    m.add_indexed(&v, &[[0, 1, 2], [0, 2, 3]], Material::DEFAULT, None)
        .unwrap();
    m
}

/// In trees larger than L2, where a subtree that one lane of a packet reaches is
/// searched by that lane's single ray, packets still answer as single rays: garden's
/// grass from points on the ground, in narrow and wide cones, with finite `tmax`.
#[test]
fn packets_in_large_trees_answer_as_single_rays() {
    use crate::sampling::rng::{hash4, to_unit_f32};
    let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 11));
    let scene = crate::scenes::load("garden", 0.25, 3).unwrap().scene;
    let bvh = scene.bvh();
    assert!(bvh.outgrows_l2(), "the test needs a tree larger than L2");
    let (mut occluded, mut open) = (0, 0);
    for (k, (p, n)) in crate::testing::surface_points(&scene, Some("ground"), 64, 7)
        .into_iter()
        .enumerate()
    {
        let origin = Vec3A::from(scene.offset_point(p, n));
        let mut hint = OccluderHint::NONE;
        for q in 0..4u64 {
            let s = 4 * k as u64 + q;
            let axis = vec3a(unit(1, s) - 0.5, unit(2, s) * 0.8 + 0.05, unit(3, s) - 0.5);
            let spread = [0.02, 0.2, 0.8][s as usize % 3];
            let dirs: Vec<Vec3A> = (0..PACKET as u64)
                .map(|l| {
                    let e = vec3a(
                        unit(4, 16 * s + l),
                        unit(5, 16 * s + l),
                        unit(6, 16 * s + l),
                    );
                    axis + (e - 0.5) * spread
                })
                .collect();
            let tmax: Vec<f32> = (0..PACKET as u64)
                .map(|l| [f32::INFINITY, 0.05, 0.3][((s + l) % 3) as usize])
                .collect();
            let mut c = TraversalCounters::default();
            let got = bvh.occluded_packet::<true>(origin, &dirs, &tmax, &mut hint, &mut c);
            let mut none = TraversalCounters::default();
            for (l, (&d, &t)) in dirs.iter().zip(&tmax).enumerate() {
                let alone = bvh.occluded::<false>(origin, d, t, &mut none);
                assert_eq!(got >> l & 1 != 0, alone, "point {k} packet {q} ray {l}");
                (occluded, open) = (occluded + alone as u32, open + !alone as u32);
            }
        }
    }
    assert!(
        occluded > 500 && open > 500,
        "{occluded} occluded, {open} open"
    );
}

#[test]
fn local_scale_is_a_power_of_two_in_range() {
    for e in [1e-4f32, 0.3, 1.0, 255.9, 256.0, 511.0, 1e4, 3e7] {
        let s = local_scale(e);
        assert_eq!(s.to_bits() & 0x007f_ffff, 0, "not a power of two: {s}");
        assert!((256.0..512.0).contains(&(e * s)), "{e} -> {}", e * s);
    }
}

#[test]
fn empty_single_and_degenerate() {
    let mut c = TraversalCounters::default();
    let empty = Bvh::build(&Mesh::new(), BuildQuality::Fast);
    let o = vec3a(0.5, 0.5, 1.0);
    let d = vec3a(0.0, 0.0, -1.0);
    assert!(!empty.occluded::<true>(o, d, f32::INFINITY, &mut c));
    assert!(empty
        .intersect::<true>(o, d, f32::INFINITY, &mut c)
        .is_none());
    assert_eq!(c.rays, 2);

    let mut m = Mesh::new();
    let v = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [2.0, 0.0, 0.0],
    ];
    m.add_indexed(&v, &[[0, 1, 3], [0, 1, 2]], Material::DEFAULT, None)
        .unwrap();
    let single = Bvh::build(&m, BuildQuality::Fast);
    assert_eq!(single.blocks.len(), 1);
    assert!(
        single.triangle_ids.iter().all(|&t| t == 1),
        "the collinear triangle is left out"
    );
    let h = single
        .intersect::<false>(vec3a(0.25, 0.25, 1.0), d, f32::INFINITY, &mut c)
        .unwrap();
    assert_eq!(h.triangle, 1);
    assert!((h.t - 1.0).abs() < 1e-6);
}

/// `Auto` keeps the PLOC tree only where it does 5% less probe work, says which and
/// why, and answers as both do; an empty mesh builds too.
#[test]
fn auto_keeps_the_cheaper_tree() {
    use crate::sampling::rng::{hash4, to_unit_f32};
    let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 23));
    let mut soup = Mesh::new();
    // Long thin slivers in random directions: trees from the two builders differ.
    let v: Vec<[f32; 3]> = (0..3000u64)
        .map(|i| {
            let s = if i % 3 == 1 { 4.0 } else { 0.1 };
            let c = i / 3;
            [
                unit(1, c) * 8.0 + unit(4, i) * s,
                unit(2, c) * 8.0 + unit(5, i) * 0.1,
                unit(3, c) * 8.0 + unit(6, i) * 0.1,
            ]
        })
        .collect();
    let faces: Vec<[i64; 3]> = (0..1000).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
    soup.add_indexed(&v, &faces, Material::DEFAULT, None)
        .unwrap();
    let sah = Bvh::build(&soup, BuildQuality::Sah);
    let ploc = Bvh::build(&soup, AUTO_ALTERNATIVE);
    let auto = Bvh::build(&soup, BuildQuality::Auto);
    assert_ne!(sah.sah_cost(), ploc.sah_cost());
    let costs = auto.auto_costs().expect("compared");
    let (s, p) = (costs.sah, costs.alternative);
    assert_eq!(costs.objects_apart, None, "one object");
    let rays = probe_rays(&soup, AUTO_PROBE_RAYS);
    assert_eq!([s, p], [sah.probe_work(&rays), ploc.probe_work(&rays)]);
    assert!(s > 1.0 && p > 1.0, "{s} {p}");
    let chosen = if s > AUTO_MARGIN * p {
        AUTO_ALTERNATIVE
    } else {
        BuildQuality::Sah
    };
    assert_eq!(auto.quality(), chosen);
    let kept = if chosen == BuildQuality::Sah {
        &sah
    } else {
        &ploc
    };
    assert_eq!(auto.sah_cost(), kept.sah_cost());
    assert_eq!(sah.auto_costs(), None);
    assert_eq!(auto.requested_quality(), BuildQuality::Auto);
    assert_eq!(sah.requested_quality(), BuildQuality::Sah);
    assert!(sah.sah_cost() > 1.0 && ploc.sah_cost() > 1.0);
    let mut c = TraversalCounters::default();
    for k in 0..2000u64 {
        let o = vec3a(unit(7, k), unit(8, k), unit(9, k)) * 10.0 - 1.0;
        let d = vec3a(unit(10, k), unit(11, k), unit(12, k)) - 0.5;
        let a = auto.intersect::<false>(o, d, f32::INFINITY, &mut c);
        let b = sah.intersect::<false>(o, d, f32::INFINITY, &mut c);
        assert_eq!(a.map(|h| (h.t, h.triangle)), b.map(|h| (h.t, h.triangle)));
    }
    let empty = Bvh::build(&Mesh::new(), BuildQuality::Auto);
    assert_eq!(empty.sah_cost(), 0.0);
    assert!(!empty.occluded::<false>(vec3a(0.0, 0.0, 1.0), vec3a(0.0, 0.0, -1.0), 1.0, &mut c));
}

/// A packet prepares each lane exactly as the single-ray traversal prepares that ray:
/// the same watertight ray (axes, shear, permuted origin), inverse direction and local
/// `tmax`, bit for bit. Directions of every octant and largest axis, with zero and
/// negative-zero components, ties between axes, tiny and huge lengths; packets of 1 to
/// 16 rays; finite and infinite `tmax`.
#[cfg(target_arch = "x86_64")]
#[test]
fn packets_prepare_each_lane_as_a_single_ray() {
    use crate::sampling::rng::{hash4, to_unit_f32};
    if !crate::simd::has(crate::simd::SimdLevel::Avx512) {
        return;
    }
    let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 33));
    let bvh = Bvh::build(&quad_mesh(3.0), BuildQuality::Sah);
    let special = [0.0, -0.0, 1.0, -1.0, 1e-20, -3e-38, 7e20];
    let mut checked = 0;
    for k in 0..400u64 {
        let count = 1 + (k as usize % PACKET);
        let origin = vec3a(unit(1, k), unit(2, k), unit(3, k)) * 20.0 - 10.0;
        let dirs: Vec<Vec3A> = (0..count as u64)
            .map(|l| {
                let s = 16 * k + l;
                let mut d = vec3a(unit(4, s), unit(5, s), unit(6, s)) * 2.0 - 1.0;
                for axis in 0..3 {
                    if unit(7 + axis as u64, s) < 0.25 {
                        d[axis] = special[(unit(10, s) * 7.0) as usize % 7];
                    }
                }
                if unit(11, s) < 0.1 {
                    d = vec3a(d.x, d.x, -d.x);
                }
                let scale = [1.0, 1e-12, 1e12][s as usize % 3];
                // Largest components that are subnormal or above 2^127, where the
                // power-of-two scaling clamps its exponent.
                let extreme = [
                    vec3a(1e-40, -3e-41, 0.0),
                    vec3a(-1.4e-45, 0.0, 1.4e-45),
                    vec3a(3e38, -1e38, 2e38),
                    vec3a(0.0, -f32::MAX, 1.0),
                ];
                match unit(12, s) {
                    u if u < 0.1 => extreme[s as usize % 4],
                    _ => d * scale,
                }
            })
            .map(|d| {
                if d.abs().max_element() > 0.0 && d.is_finite() {
                    d
                } else {
                    Vec3A::X
                }
            })
            .collect();
        let tmax: Vec<f32> = (0..count)
            .map(|l| [f32::INFINITY, 2.5, 1e-3, 0.0, f32::MAX][(k as usize + l) % 5])
            .collect();
        // SAFETY: the CPU has AVX-512 F.
        let packet = unsafe { Packet::new(&bvh, origin, &dirs, &tmax) };
        let singles: [LocalRay; PACKET] = std::array::from_fn(|l| {
            let s = l.min(count - 1);
            bvh.local_ray(origin, dirs[s], tmax[s])
        });
        // SAFETY: as above.
        let gathered = unsafe { WatertightPacket::new(&singles.map(|r| r.watertight)) };
        assert_eq!(packet.watertight.bits(), gathered.bits(), "packet {k}");
        let inverse = packet.inverse.map(lanes);
        for (l, r) in singles.iter().enumerate() {
            let ray = packet.watertight.lane_ray(l);
            assert_eq!(ray.bits(), r.watertight.bits(), "packet {k} lane {l}");
            assert_eq!(lanes(packet.tmax)[l].to_bits(), r.tmax.to_bits());
            let (o, inv) = r.boxes.origin_and_inverse();
            for axis in 0..3 {
                assert_eq!(inverse[axis][l].to_bits(), inv[axis].to_bits());
            }
            assert_eq!(o.map(f32::to_bits), ray.bits()[..3]);
            checked += 1;
        }
    }
    assert_eq!(checked, 400 * PACKET);
}

/// Each lane of the packet's box test hits the children its ray's own box test hits,
/// and the packet's interval test keeps every child that some lane hits, on every node
/// of a random soup's tree, for packets narrow and wide, with lanes of one sign and of
/// mixed signs per axis, axis-parallel directions and finite `tmax`.
#[cfg(target_arch = "x86_64")]
#[test]
fn packet_interval_test_keeps_every_child_a_lane_touches() {
    use crate::sampling::rng::{hash4, to_unit_f32};
    if !crate::simd::has(crate::simd::SimdLevel::Avx512) {
        return;
    }
    let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 21));
    let mut soup = Mesh::new();
    let v: Vec<[f32; 3]> = (0..3000u64)
        .map(|i| [unit(1, i) * 8.0, unit(2, i) * 8.0, unit(3, i) * 8.0])
        .collect();
    let faces: Vec<[i64; 3]> = (0..1000).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
    soup.add_indexed(&v, &faces, Material::DEFAULT, None)
        .unwrap();
    let bvh = Bvh::build(&soup, BuildQuality::Medium);
    let (mut kept, mut culled) = (0u64, 0u64);
    for k in 0..300u64 {
        let origin = vec3a(unit(4, k), unit(5, k), unit(6, k)) * 10.0 - 1.0;
        let axis = vec3a(unit(7, k), unit(8, k), unit(9, k)) - 0.5;
        let spread = [0.02, 0.3, 2.0][k as usize % 3];
        let dirs: Vec<Vec3A> = (0..PACKET as u64)
            .map(|l| {
                let s = 16 * k + l;
                let d = axis + (vec3a(unit(10, s), unit(11, s), unit(12, s)) - 0.5) * spread;
                if s % 11 == 0 {
                    vec3a(d.x, 0.0, d.z)
                } else {
                    d
                }
            })
            .filter(|d| d.length() > 0.0)
            .collect();
        let tmax: Vec<f32> = (0..dirs.len())
            .map(|l| [f32::INFINITY, 3.0, 0.5][(k as usize + l) % 3])
            .collect();
        // SAFETY: the CPU has AVX-512 F.
        let packet = unsafe { Packet::new(&bvh, origin, &dirs, &tmax) };
        let single: Vec<LocalRay> = (0..dirs.len())
            .map(|l| bvh.local_ray(origin, dirs[l], tmax[l]))
            .collect();
        for n in &bvh.tree.nodes {
            // SAFETY: as above.
            let relative = unsafe { packet.relative_planes(n) };
            // SAFETY: as above.
            let touched = unsafe { packet.children_touched(&relative) };
            let alone: Vec<u32> = single
                .iter()
                .map(|r| n.intersect(&r.boxes, r.tmax).1)
                .collect();
            for j in 0..WIDTH {
                // SAFETY: as above.
                let lanes = unsafe { packet.box_hits(&relative, j, packet.all) };
                for (l, a) in alone.iter().enumerate() {
                    assert_eq!(
                        u32::from(lanes >> l & 1),
                        a >> j & 1,
                        "packet {k}, lane {l}, child {j}"
                    );
                }
                if lanes != 0 {
                    assert!(touched >> j & 1 != 0, "packet {k}: child {j} culled");
                    kept += 1;
                } else if touched >> j & 1 == 0 {
                    culled += 1;
                }
            }
        }
    }
    assert!(
        kept > 1000 && culled > 10_000,
        "kept {kept}, culled {culled}"
    );
}

/// Packets answer as single rays, bit for bit: a random soup and a grid of
/// axis-aligned quads (rays in their planes and through shared edges), packets of 1 to
/// 16 rays in narrow and wide cones, axis-aligned directions, finite and infinite
/// `tmax`, consecutive packets sharing a hint. Counters count every ray.
#[test]
fn packets_answer_as_single_rays() {
    use crate::sampling::rng::{hash4, to_unit_f32};
    let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 9));
    let soup = triangle_soup(9);
    let mut grid = Mesh::new();
    for (i, j) in (0..4).flat_map(|i| (0..4).map(move |j| (i, j))) {
        let (x, y) = (i as f32, j as f32);
        let quad = [
            [x, y, 1.0],
            [x + 1.0, y, 1.0],
            [x + 1.0, y + 1.0, 1.0],
            [x, y + 1.0, 1.0],
        ];
        grid.add_indexed(&quad, &[[0, 1, 2], [0, 2, 3]], Material::DEFAULT, None)
            .unwrap();
    }
    // Each triangle of the soup a group of its own, the groups chained: a tree too deep
    // for the fixed stack.
    let groups: Vec<_> = (0..600).map(|i| i..i + 1).collect();
    let deep = Bvh::build_chained(&soup, BuildQuality::Sah, &groups);
    assert!(!deep.stack_is_bounded(), "depth {}", deep.depth());
    let mut tested = 0;
    for (bvh, centre) in [
        (
            Bvh::build(&soup, BuildQuality::Medium),
            vec3a(2.0, 2.0, 2.0),
        ),
        (deep, vec3a(2.0, 2.0, 2.0)),
        (
            Bvh::build(&grid, BuildQuality::Medium),
            vec3a(2.0, 2.0, 0.0),
        ),
    ] {
        for k in 0..400u64 {
            let origin = centre + (vec3a(unit(7, k), unit(8, k), unit(9, k)) - 0.5) * 3.0;
            let origin = if k % 5 == 0 { origin.round() } else { origin };
            let axis = vec3a(unit(10, k), unit(11, k), unit(12, k)) - 0.5;
            let spread = [0.05, 0.5, 3.0][k as usize % 3];
            let mut hint = OccluderHint::NONE;
            for p in 0..3u64 {
                let count = 1 + ((k + p) % PACKET as u64) as usize;
                let dirs: Vec<Vec3A> = (0..count as u64)
                    .map(|l| {
                        let s = 64 * k + 16 * p + l;
                        let d =
                            axis + (vec3a(unit(13, s), unit(14, s), unit(15, s)) - 0.5) * spread;
                        match s % 7 {
                            0 => vec3a(0.0, 0.0, d.z.signum()),
                            1 => vec3a(d.x, d.y, 0.0),
                            _ => d,
                        }
                    })
                    .filter(|d| d.length() > 0.0)
                    .collect();
                let tmax: Vec<f32> = (0..dirs.len() as u64)
                    .map(|l| [f32::INFINITY, 0.5, 2.0, 0.0][((k + l) % 4) as usize])
                    .collect();
                let mut c = TraversalCounters::default();
                let got = bvh.occluded_packet::<true>(origin, &dirs, &tmax, &mut hint, &mut c);
                assert_eq!(c.rays, dirs.len() as u64);
                let mut none = TraversalCounters::default();
                for (l, (&d, &t)) in dirs.iter().zip(&tmax).enumerate() {
                    let alone = bvh.occluded::<false>(origin, d, t, &mut none);
                    assert_eq!(got >> l & 1 != 0, alone, "k {k} packet {p} ray {l}");
                    tested += alone as usize;
                }
                assert_eq!(got as u32 >> dirs.len(), 0);
            }
        }
    }
    assert!(tested > 1000, "{tested} occluded rays");
}

/// Closest-hit packets find every lane's single-ray distance: random soups in a shallow and
/// a deep tree (fixed and spilling stacks), a grid of quads, and camera-like packets into
/// garden's large tree; narrow to wide spreads, finite `tmax`, 1 to 16 lanes. Where the
/// triangle differs, another triangle lies at exactly that distance (a shared edge).
#[test]
fn closest_packets_find_the_single_rays_hits() {
    use crate::sampling::rng::{hash4, to_unit_f32};
    let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 21));
    let soup = triangle_soup(21);
    let groups: Vec<_> = (0..600).map(|i| i..i + 1).collect();
    let deep = Bvh::build_chained(&soup, BuildQuality::Sah, &groups);
    assert!(!deep.stack_is_bounded());
    let garden = crate::scenes::load("garden", 0.25, 3).unwrap().scene;
    let trees: [(&Bvh, Vec3A, f32); 4] = [
        (
            &Bvh::build(&soup, BuildQuality::Medium),
            vec3a(2.0, 2.0, 2.0),
            3.0,
        ),
        (&deep, vec3a(2.0, 2.0, 2.0), 3.0),
        (
            &Bvh::build(&quad_mesh(4.0), BuildQuality::Medium),
            vec3a(2.0, 2.0, 1.0),
            3.0,
        ),
        (garden.bvh(), vec3a(0.0, 1.5, 6.0), 2.0),
    ];
    let (mut hits, mut misses, mut ties) = (0u32, 0u32, 0u32);
    for (bvh, centre, size) in trees {
        let target = vec3a(0.0, 0.3, 0.0);
        for k in 0..300u64 {
            let origin = centre + (vec3a(unit(7, k), unit(8, k), unit(9, k)) - 0.5) * size;
            let axis = if k % 2 == 0 {
                target - origin
            } else {
                vec3a(unit(10, k), unit(11, k), unit(12, k)) - 0.5
            };
            let spread = [0.002, 0.05, 0.5, 3.0][k as usize % 4];
            let count = 1 + (k % PACKET as u64) as usize;
            let dirs: Vec<Vec3A> = (0..count as u64)
                .map(|l| {
                    let s = 16 * k + l;
                    axis + (vec3a(unit(13, s), unit(14, s), unit(15, s)) - 0.5) * spread
                })
                .collect();
            let tmax: Vec<f32> = (0..count as u64)
                .map(|l| [f32::INFINITY, 0.5, 3.0][((k + l) % 3) as usize])
                .collect();
            let mut c = TraversalCounters::default();
            let got = bvh.intersect_packet::<true>(origin, &dirs, &tmax, &mut c);
            assert_eq!(c.rays, count as u64);
            assert!(got[count..].iter().all(Option::is_none));
            let mut none = TraversalCounters::default();
            for (l, (&d, &t)) in dirs.iter().zip(&tmax).enumerate() {
                let alone = bvh.intersect::<false>(origin, d, t, &mut none);
                match (got[l], alone) {
                    (Some(a), Some(b)) => {
                        assert_eq!(a.t.to_bits(), b.t.to_bits(), "k {k} ray {l}");
                        if a.triangle == b.triangle {
                            assert_eq!((a.u, a.v), (b.u, b.v), "k {k} ray {l}");
                        } else {
                            ties += 1;
                        }
                        hits += 1;
                    }
                    (None, None) => misses += 1,
                    (a, b) => panic!("k {k} ray {l}: packet {a:?}, alone {b:?}"),
                }
            }
        }
    }
    assert!(hits > 2000 && misses > 500, "{hits} hits, {misses} misses");
    assert!(ties * 100 < hits, "{ties} ties of {hits} hits");
}

/// The portable traversals (for CPUs without AVX2) and every vector one this CPU can run
/// give the same answers and the same counts, any-hit and closest-hit, on a random soup
/// in a shallow tree (traversed with the fixed stack) and in one too deep for it (with
/// the spilling stack): rays from inside and outside, axis-parallel and with zero
/// components, finite `tmax`.
#[cfg(target_arch = "x86_64")]
#[test]
fn vector_and_portable_traversals_agree() {
    use crate::sampling::rng::{hash4, to_unit_f32};
    use crate::simd::SimdLevel;
    if !crate::simd::has(SimdLevel::Avx2) {
        return;
    }
    let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 33));
    let mut soup = Mesh::new();
    let v: Vec<[f32; 3]> = (0..6000u64)
        .map(|i| {
            let c = (i / 3) as f32;
            [
                unit(1, i) + c % 7.0,
                unit(2, i) * 2.0,
                unit(3, i) + c % 11.0,
            ]
        })
        .collect();
    let faces: Vec<[i64; 3]> = (0..2000).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
    soup.add_indexed(&v, &faces, Material::DEFAULT, None)
        .unwrap();
    let soup_rays = |k: u64| {
        let o = vec3a(
            unit(4, k) * 10.0 - 1.5,
            unit(5, k) * 4.0 - 1.0,
            unit(6, k) * 13.0 - 1.0,
        );
        let mut d = vec3a(unit(7, k), unit(8, k), unit(9, k)) - 0.5;
        match k % 5 {
            0 => d.y = 0.0,
            1 => d = vec3a(0.0, 0.0, -1.0),
            _ => {}
        }
        (o, d, [f32::INFINITY, 1.0, 4.0][k as usize % 3])
    };
    // The soup's first 400 triangles each as a group of its own, their subtrees chained
    // one above the other: far deeper than any SAH tree.
    let groups: Vec<_> = (0..400).map(|i| i..i + 1).collect();
    for (name, groups, bounded) in [("soup", &groups[..0], true), ("deep", &groups[..], false)] {
        let bvh = Bvh::build_chained(&soup, BuildQuality::Sah, groups);
        assert_eq!(
            bvh.stack_is_bounded(),
            bounded,
            "{name}: depth {}",
            bvh.depth()
        );
        let (mut occluded, mut hit, mut missed) = (0, 0, 0);
        for k in 0..4000u64 {
            let (o, d, tmax) = soup_rays(k);
            if d.length() == 0.0 {
                continue;
            }
            let mut c = TraversalCounters::default();
            let mut hint = OccluderHint::NONE;
            let ray = HintedRay::<true> {
                bvh: &bvh,
                origin: o,
                direction: d,
                tmax,
                hint: &mut hint,
                counters: &mut c,
            };
            let portable = crate::simd::run_at(SimdLevel::Portable, ray).expect("any CPU");
            let mut ch = TraversalCounters::default();
            let r = bvh.local_ray(o, d, tmax);
            let closest = bvh.closest_hit::<true, Stack<_, STACK>>(&r, &mut ch, PortableBoxTest);
            let bits = |h: Option<Hit>| {
                h.map(|h| (h.t.to_bits(), h.triangle, h.u.to_bits(), h.v.to_bits()))
            };
            for simd in [SimdLevel::Avx2, SimdLevel::Avx512] {
                if !crate::simd::has(simd) {
                    continue;
                }
                let (mut c2, mut ch2) =
                    (TraversalCounters::default(), TraversalCounters::default());
                let mut hint2 = OccluderHint::NONE;
                let ray = HintedRay::<true> {
                    bvh: &bvh,
                    origin: o,
                    direction: d,
                    tmax,
                    hint: &mut hint2,
                    counters: &mut c2,
                };
                let vector = crate::simd::run_at(simd, ray).expect("the CPU has it");
                let ray = ClosestRay::<true> {
                    bvh: &bvh,
                    origin: o,
                    direction: d,
                    tmax,
                    counters: &mut ch2,
                };
                let vector_closest = crate::simd::run_at(simd, ray).expect("the CPU has it");
                assert_eq!(
                    (portable, hint, c),
                    (vector, hint2, c2),
                    "{name} {simd:?} ray {k}"
                );
                assert_eq!(
                    (bits(closest), ch),
                    (bits(vector_closest), ch2),
                    "{name} {simd:?} ray {k}"
                );
            }
            occluded += portable as u32;
            hit += closest.is_some() as u32;
            missed += closest.is_none() as u32;
        }
        assert!(
            occluded > 500 && hit > 500 && missed > 500,
            "{name}: {occluded} occluded, {hit} hit, {missed} missed"
        );
    }
}

#[test]
fn scale_invariant_answers() {
    for scale in [1e-4f32, 1.0, 1e4] {
        let bvh = Bvh::build(&quad_mesh(scale), BuildQuality::Fast);
        let mut c = TraversalCounters::default();
        // Direction of arbitrary length: t stays in its units.
        let o = vec3a(0.5, 0.25, 2.0) * scale;
        let h = bvh.intersect::<true>(o, vec3a(0.0, 0.0, -4.0), f32::INFINITY, &mut c);
        let h = h.unwrap();
        assert!((h.t - 0.5 * scale).abs() <= 1e-6 * scale, "{scale}: {h:?}");
        assert!(bvh.occluded::<true>(o, vec3a(0.0, 0.0, -1.0), 2.001 * scale, &mut c));
        assert!(!bvh.occluded::<true>(o, vec3a(0.0, 0.0, -1.0), 1.999 * scale, &mut c));
        assert!(c.nodes >= 3 && c.triangles >= 3, "{c:?}");
    }
}

#[test]
fn refit_keeps_exact_boxes_and_detects_degeneracy_changes() {
    let mut m = quad_mesh(1.0);
    let v = [
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 1.0],
        [0.0, 1.0, 1.0],
        [5.0, 5.0, 5.0],
    ];
    m.add_indexed(&v, &[[0, 1, 2], [3, 3, 3]], Material::DEFAULT, None)
        .unwrap();
    let built = Bvh::build(&m, BuildQuality::Medium);
    let mut refit = built.clone();
    // Unmoved: every box and triangle block comes out as the build made it.
    assert!(refit.refit(&m, 0..4));
    assert_eq!(
        format!("{:?}", refit.tree.nodes),
        format!("{:?}", built.tree.nodes)
    );
    assert_eq!(format!("{:?}", refit.blocks), format!("{:?}", built.blocks));
    // Moved: the boxes follow.
    let mut moved = m.clone();
    for t in &mut moved.triangles[2..3] {
        *t = t.map(|v| v + Vec3::new(0.0, 0.0, 2.0));
    }
    assert!(refit.refit(&moved, 2..4));
    let mut c = TraversalCounters::default();
    let o = vec3a(0.25, 0.25, 10.0);
    let d = vec3a(0.0, 0.0, -1.0);
    let h = refit
        .intersect::<true>(o, d, f32::INFINITY, &mut c)
        .unwrap();
    assert_eq!((h.triangle, h.t), (2, 7.0));
    // A triangle that becomes degenerate, or stops being so, needs a rebuild.
    let mut flat = m.clone();
    flat.triangles[2][2] = flat.triangles[2][1];
    assert!(!built.clone().refit(&flat, 2..3));
    let mut grown = m.clone();
    grown.triangles[3] = [Vec3::ZERO, Vec3::X, Vec3::Y];
    assert!(!built.clone().refit(&grown, 3..4));
    assert!(built.clone().refit(&grown, 0..2), "unchanged part");
    assert!(
        !built.clone().refit(&quad_mesh(1.0), 0..2),
        "other triangle count"
    );
    // Out of the f32 range in the local frame.
    let mut far = quad_mesh(1e-3);
    far.triangles[0][0] = Vec3::splat(3e38);
    let small = Bvh::build(&quad_mesh(1e-3), BuildQuality::Fast);
    assert!(!small.clone().refit(&far, 0..1));
}

#[test]
fn grouped_builds_answer_as_whole_ones() {
    // A ground quad, a small soup, a one-triangle group, a group of degenerate
    // triangles only and an empty group.
    let mut m = quad_mesh(4.0);
    let mut tris = Vec::new();
    for i in 0..40 {
        let c = Vec3::new(
            (i % 7) as f32 * 0.5,
            0.2 + (i % 3) as f32 * 0.3,
            (i / 7) as f32 * 0.6,
        );
        tris.push([
            c,
            c + Vec3::new(0.3, 0.1, 0.0),
            c + Vec3::new(0.0, 0.2, 0.3),
        ]);
    }
    m.add_triangles(tris, Material::DEFAULT, None).unwrap();
    m.add_triangles([[Vec3::Z, Vec3::ONE, Vec3::Y]], Material::DEFAULT, None)
        .unwrap();
    m.add_triangles([[Vec3::X; 3], [Vec3::Y; 3]], Material::DEFAULT, None)
        .unwrap();
    let whole = Bvh::build(&m, BuildQuality::Medium);
    for groups in [
        vec![2usize..42; 1],
        vec![2..42, 42..43, 43..45, 45..45],
        vec![0usize..45; 1],
    ] {
        let grouped = Bvh::build_grouped(&m, BuildQuality::Medium, &groups);
        assert_eq!(grouped.triangle_ids.iter().max(), Some(&42), "{groups:?}");
        let origins = (vec3a(0.0, -0.5, 0.0), vec3a(4.0, 2.0, 4.0));
        assert_same_answers(&whole, &grouped, origins, 2000, 1.0, 5);
    }
}

/// A 20-unit ground grid of `cells` x `cells` squares with `objects` small boxes of 12
/// triangles just above it in a row, each box an object of its own (`meshes`' layout in
/// miniature).
fn ground_and_boxes(cells: usize, objects: usize) -> Mesh {
    let mut m = Mesh::new();
    let mut ground = Vec::new();
    let side = 20.0 / cells as f32;
    for i in 0..cells {
        for j in 0..cells {
            let p = Vec3::new(i as f32 * side - 10.0, 0.0, j as f32 * side - 10.0);
            let (x, z) = (Vec3::X * side, Vec3::Z * side);
            ground.push([p, p + x, p + x + z]);
            ground.push([p, p + x + z, p + z]);
        }
    }
    m.add_triangles(ground, Material::DEFAULT, Some("ground".into()))
        .unwrap();
    for k in 0..objects {
        // Clear of the ground, so that no hit ties between a box and a ground cell.
        let lo = Vec3::new(-8.0 + 16.0 * k as f32 / objects as f32, 0.01, 0.0);
        let hi = lo + Vec3::new(0.4 * 16.0 / objects as f32, 1.0, 0.5);
        let corner = |b: usize| {
            Vec3::new(
                [lo.x, hi.x][b & 1],
                [lo.y, hi.y][b >> 1 & 1],
                [lo.z, hi.z][b >> 2 & 1],
            )
        };
        let faces = [
            [0, 1, 3, 2],
            [4, 6, 7, 5],
            [0, 4, 5, 1],
            [2, 3, 7, 6],
            [0, 2, 6, 4],
            [1, 5, 7, 3],
        ];
        let tris = faces.iter().flat_map(|f| {
            let c = f.map(corner);
            [[c[0], c[1], c[2]], [c[0], c[2], c[3]]]
        });
        m.add_triangles(tris, Material::DEFAULT, None).unwrap();
    }
    m
}

/// Closest hits and shadow answers (to `tmax`) of `a` and `b` agree on `rays` random rays
/// (stream `seed`) from origins uniform in the box at `low` of size `extent`.
fn assert_same_answers(
    a: &Bvh,
    b: &Bvh,
    (low, extent): (Vec3A, Vec3A),
    rays: u32,
    tmax: f32,
    seed: u64,
) {
    let mut c = TraversalCounters::default();
    for i in 0..rays {
        let r = crate::sampling::rng::SampleRng::new(seed, i as u64, 0);
        let o = low + Vec3A::new(r.get(0), r.get(1), r.get(2)) * extent;
        let [u, v] = r.get2(3);
        let d = Vec3A::from(crate::scenes::shapes::sphere_dir(u, v));
        let (x, y) = (
            a.intersect::<true>(o, d, f32::INFINITY, &mut c),
            b.intersect::<true>(o, d, f32::INFINITY, &mut c),
        );
        assert_eq!(
            x.map(|h| (h.t, h.triangle)),
            y.map(|h| (h.t, h.triangle)),
            "{i}"
        );
        assert_eq!(
            a.occluded::<true>(o, d, tmax, &mut c),
            b.occluded::<true>(o, d, tmax, &mut c),
            "{i}"
        );
    }
}

/// Origins over [`ground_and_boxes`]' ground, up to 1.5 above it.
const OVER_THE_GROUND: (Vec3A, Vec3A) = (vec3a(-10.0, 0.0, -10.0), vec3a(20.0, 1.5, 20.0));

/// Many objects apart get a balanced top (a chain of joins would be about one level per
/// seven objects deep) and answer as the tree over all triangles at once.
#[test]
fn objects_apart_are_joined_into_a_balanced_top() {
    let m = ground_and_boxes(40, 300);
    let objects: Vec<_> = m.objects.iter().map(|o| o.triangle_range()).collect();
    let apart = Bvh::build_grouped(&m, BuildQuality::Sah, &objects);
    let whole = Bvh::build(&m, BuildQuality::Sah);
    // 301 subtrees need ceil(log8 301) = 3 levels above them; a box is one leaf deep.
    assert!(
        apart.depth() <= whole.depth() + 3,
        "{} {}",
        apart.depth(),
        whole.depth()
    );
    assert!(apart.depth() <= 8, "{}", apart.depth());
    assert_same_answers(&apart, &whole, OVER_THE_GROUND, 4000, 3.0, 9);
}

/// `Auto` also weighs the SAH tree with each object apart, on a mesh of several objects,
/// and keeps it where it does 5% less probe work than the plain SAH tree and less than
/// the PLOC tree: here, where boxes stand on a ground grid as in `meshes`. The kept tree
/// is that build, for any thread count, and answers as the plain SAH tree does. Where
/// one object holds more than [`AUTO_APART_LARGEST`] of the triangles (a finer ground),
/// that tree is not built.
#[test]
fn auto_keeps_objects_apart_where_they_save_work() {
    let fine = ground_and_boxes(40, 6);
    assert!(3200.0 / fine.triangles.len() as f64 > AUTO_APART_LARGEST);
    let costs = Bvh::build(&fine, BuildQuality::Auto)
        .auto_costs()
        .expect("compared");
    assert_eq!(costs.objects_apart, None);
    let m = ground_and_boxes(8, 6);
    assert!(128.0 / m.triangles.len() as f64 <= AUTO_APART_LARGEST);
    let auto = Bvh::build(&m, BuildQuality::Auto);
    let costs = auto.auto_costs().expect("compared");
    let objects: Vec<_> = m.objects.iter().map(|o| o.triangle_range()).collect();
    let apart = Bvh::build_grouped(&m, BuildQuality::Sah, &objects);
    let sah = Bvh::build(&m, BuildQuality::Sah);
    let rays = probe_rays(&m, AUTO_PROBE_RAYS);
    assert_eq!(costs.objects_apart, Some(apart.probe_work(&rays)));
    assert_eq!(costs.sah, sah.probe_work(&rays));
    assert!(
        costs.sah > AUTO_MARGIN * costs.objects_apart.unwrap(),
        "{costs:?}"
    );
    assert_eq!(costs.chosen(), AutoChoice::ObjectsApart, "{costs:?}");
    assert!(auto.objects_apart() && !sah.objects_apart());
    assert_eq!(auto.quality(), BuildQuality::Sah);
    assert_eq!(auto.sah_cost(), apart.sah_cost());
    assert_eq!(auto.triangle_ids, apart.triangle_ids);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let single = one.install(|| Bvh::build(&m, BuildQuality::Auto));
    assert_eq!(single.triangle_ids, auto.triangle_ids);
    assert_eq!(single.auto_costs(), auto.auto_costs());
    assert_same_answers(&auto, &sah, OVER_THE_GROUND, 4000, 3.0, 9);
}

/// The rule of [`AutoCosts::chosen`]: the plain SAH tree unless another does more than
/// 5% less work, then the least-work one (PLOC on a tie).
#[test]
fn auto_choice_rule() {
    let costs = |sah, alternative, objects_apart| AutoCosts {
        sah,
        alternative,
        objects_apart,
    };
    assert_eq!(costs(1.0, 0.96, None).chosen(), AutoChoice::Sah);
    assert_eq!(costs(1.0, 0.9, None).chosen(), AutoChoice::Alternative);
    assert_eq!(
        costs(1.0, 0.9, Some(0.8)).chosen(),
        AutoChoice::ObjectsApart
    );
    assert_eq!(costs(1.0, 0.8, Some(0.9)).chosen(), AutoChoice::Alternative);
    assert_eq!(costs(1.0, 0.8, Some(0.8)).chosen(), AutoChoice::Alternative);
    assert_eq!(costs(1.0, 1.2, Some(0.97)).chosen(), AutoChoice::Sah);
    assert_eq!(
        costs(1.0, 1.2, Some(0.9)).chosen(),
        AutoChoice::ObjectsApart
    );
}
