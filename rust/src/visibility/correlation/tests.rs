//! Correlation measurements against brute force: ρ from popcounts against a direct f64
//! Pearson over the bits (random, identical, complementary, constant maps), bins against a
//! plain loop, traced maps against `Record::trace`, pairs' structure and determinism for
//! 1 and 2 threads, local correlation against a plain loop, bad arguments.

use super::*;
use crate::scenes;
use crate::testing::surface_points;

/// Pearson correlation of two 0/1 sequences computed directly in f64 (None: zero variance).
fn direct_pearson(x: &[bool], y: &[bool]) -> Option<f64> {
    let n = x.len() as f64;
    let mx = x.iter().filter(|b| **b).count() as f64 / n;
    let my = y.iter().filter(|b| **b).count() as f64 / n;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        let (dx, dy) = (*a as u8 as f64 - mx, *b as u8 as f64 - my);
        sxy += dx * dy;
        sxx += dx * dx;
        syy += dy * dy;
    }
    if sxx == 0.0 || syy == 0.0 {
        None
    } else {
        Some(sxy / (sxx * syy).sqrt())
    }
}

fn words_of(bits: &[bool]) -> Vec<u64> {
    let mut w = vec![0u64; bits.len().div_ceil(64)];
    for (z, &b) in bits.iter().enumerate() {
        w[z / 64] |= (b as u64) << (z % 64);
    }
    w
}

/// Random maps: map `i` has visibility probability `p_i` from a hash, so some are nearly
/// constant and pairs span a range of ρ; map 0 all occluded, map 1 all visible, map 2 a
/// copy of map 3, map 4 map 3's complement.
fn random_maps(n: usize, m: u32, seed: u64) -> (Vec<Vec<bool>>, VisibilityMaps) {
    let len = 1usize << (2 * m);
    let mut maps: Vec<Vec<bool>> = (0..n)
        .map(|i| {
            let p = to_unit_f64(hash4(seed, i as u64, 0, 99));
            (0..len)
                .map(|z| to_unit_f64(hash4(seed, i as u64, z as u64, 1)) < p)
                .collect()
        })
        .collect();
    maps[0] = vec![false; len];
    maps[1] = vec![true; len];
    maps[2] = maps[3].clone();
    maps[4] = maps[3].iter().map(|b| !b).collect();
    let words: Vec<u64> = maps.iter().flat_map(|b| words_of(b)).collect();
    let points: Vec<Vec3> = (0..n)
        .map(|i| {
            let u = |d| to_unit_f64(hash4(seed, i as u64, 1, d)) as f32;
            Vec3::new(u(0), u(1), u(2)) * 4.0
        })
        .collect();
    let normals: Vec<Vec3> = (0..n)
        .map(|i| {
            let u = |d| to_unit_f64(hash4(seed, i as u64, 2, d)) as f32;
            Vec3::new(u(0) - 0.5, 1.0, u(1) - 0.5)
        })
        .collect();
    let vm = VisibilityMaps::from_bit_words(m, words, points, normals).unwrap();
    (maps, vm)
}

#[test]
fn rho_from_popcounts_equals_direct_pearson() {
    for m in [1u32, 3, 5] {
        let (bits, maps) = random_maps(24, m, 7 + m as u64);
        for i in 0..maps.len() {
            for j in 0..maps.len() {
                let direct = direct_pearson(&bits[i], &bits[j]);
                let fast = maps.rho(i, j);
                match (direct, fast) {
                    (None, None) => {}
                    (Some(a), Some(b)) => {
                        // Both are within a few ulps of the exact value; the direct sum over
                        // 4^M terms accumulates ~4^M ulps of error at most.
                        let tol = 1e-15 * (1usize << (2 * m)) as f64 + 1e-14;
                        assert!((a - b).abs() <= tol, "m {m} ({i},{j}): {a} vs {b}");
                    }
                    _ => panic!("m {m} ({i},{j}): direct {direct:?}, popcount {fast:?}"),
                }
            }
        }
        // Constant maps are undefined against anything, including themselves.
        for j in 0..maps.len() {
            assert_eq!(maps.rho(0, j), None);
            assert_eq!(maps.rho(1, j), None);
        }
        assert_eq!(maps.rho(2, 3), Some(1.0), "identical maps");
        assert_eq!(maps.rho(3, 4), Some(-1.0), "complementary maps");
        assert_eq!(maps.rho(3, 3), Some(1.0));
    }
}

#[test]
fn pearson_extremes() {
    assert_eq!(pearson_from_counts(4, 0, 2, 0), None);
    assert_eq!(pearson_from_counts(4, 4, 2, 2), None);
    assert_eq!(pearson_from_counts(4, 2, 0, 0), None);
    assert_eq!(pearson_from_counts(4, 2, 4, 2), None);
    assert_eq!(pearson_from_counts(4, 2, 2, 2), Some(1.0));
    assert_eq!(pearson_from_counts(4, 2, 2, 0), Some(-1.0));
    assert_eq!(pearson_from_counts(4, 2, 2, 1), Some(0.0));
    // Largest maps (128 x 128): one direction differs out of 16384.
    let n = 1u64 << 14;
    let r = pearson_from_counts(n, n / 2, n / 2 + 1, n / 2).unwrap();
    let exact =
        ((n / 2) as f64 * (n / 2 - 1) as f64 / ((n / 2) as f64 * (n / 2 + 1) as f64)).sqrt();
    assert!((r - exact).abs() < 1e-15, "{r} vs {exact}");
}

/// The bins by a plain loop: (count, sum ρ, sum ρ², undefined) per bin, outside.
fn brute_bins(
    maps: &VisibilityMaps,
    pairs: &[[u32; 2]],
    de: &[f64],
    te: &[f64],
) -> (Vec<(u64, f64, f64, u64)>, u64) {
    let nt = te.len() - 1;
    let mut bins = vec![(0u64, 0.0, 0.0, 0u64); (de.len() - 1) * nt];
    let mut outside = 0;
    for p in pairs {
        let (i, j) = (p[0] as usize, p[1] as usize);
        let (d, t) = maps.distance_angle(i, j);
        let find = |e: &[f64], x: f64| {
            (0..e.len() - 1)
                .find(|&k| x >= e[k] && (x < e[k + 1] || (k == e.len() - 2 && x == e[k + 1])))
        };
        match (find(de, d), find(te, t)) {
            (Some(a), Some(b)) => {
                let bin = &mut bins[a * nt + b];
                match maps.rho(i, j) {
                    Some(r) => {
                        bin.0 += 1;
                        bin.1 += r;
                        bin.2 += r * r;
                    }
                    None => bin.3 += 1,
                }
            }
            _ => outside += 1,
        }
    }
    (bins, outside)
}

fn assert_bins_match(got: &CorrelationBins, want: &[(u64, f64, f64, u64)], outside: u64) {
    assert_eq!(got.outside, outside);
    for (k, (m, w)) in got.moments.iter().zip(want).enumerate() {
        assert_eq!(m.count, w.0, "bin {k} count");
        assert_eq!(got.undefined[k], w.3, "bin {k} undefined");
        if w.0 == 0 {
            assert!(m.std().is_nan());
            continue;
        }
        let mean = w.1 / w.0 as f64;
        let var = (w.2 / w.0 as f64 - mean * mean).max(0.0);
        // |ρ| <= 1: sums over c values carry ~c ulps; the E[ρ²] − E[ρ]² form loses the
        // variance's leading digits to cancellation, ~c ulps of 1 absolute.
        let tol = 1e-14 * w.0 as f64 + 1e-13;
        assert!(
            (m.mean - mean).abs() <= tol,
            "bin {k}: {} vs {mean}",
            m.mean
        );
        assert!(
            (m.std() * m.std() - var).abs() <= tol,
            "bin {k}: var {} vs {var}",
            m.std() * m.std()
        );
    }
}

#[test]
fn bins_equal_a_plain_loop_for_all_pairs_and_for_lists() {
    let (_, maps) = random_maps(150, 4, 3);
    let de = [0.0, 0.5, 1.0, 2.0, 3.0, 5.0];
    let te = [0.0, 5.0, 20.0, 45.0, 90.0];
    let all: Vec<[u32; 2]> = (0..150u32)
        .flat_map(|i| (i + 1..150).map(move |j| [i, j]))
        .collect();
    let (want, outside) = brute_bins(&maps, &all, &de, &te);
    let got = correlation_bins(&maps, Pairs::All, &de, &te, Some(2)).unwrap();
    assert_eq!(got.pairs, all.len() as u64);
    assert_bins_match(&got, &want, outside);
    assert!(got.moments.iter().filter(|m| m.count > 0).count() > 10);
    assert!(
        got.undefined.iter().sum::<u64>() >= 2 * 148,
        "maps 0 and 1 are constant"
    );

    // A list longer than one chunk, with repeats, self-pairs and pairs outside the edges.
    let list: Vec<[u32; 2]> = (0..3 * PAIR_CHUNK as u64 + 17)
        .map(|k| {
            let i = (hash4(5, k, 0, 0) % 150) as u32;
            let j = (hash4(5, k, 0, 1) % 150) as u32;
            [i, j]
        })
        .collect();
    let (want, outside) = brute_bins(&maps, &list, &de[..4], &te);
    let got = correlation_bins(&maps, Pairs::List(&list), &de[..4], &te, Some(1)).unwrap();
    assert!(outside > 0);
    assert_eq!(got.pairs, list.len() as u64);
    assert_bins_match(&got, &want, outside);
    let two = correlation_bins(&maps, Pairs::List(&list), &de[..4], &te, Some(2)).unwrap();
    assert_eq!(got, two, "bit-identical for 1 and 2 threads");
}

#[test]
fn bin_edges_follow_numpy_histogram() {
    let e = [0.0, 1.0, 2.0];
    assert_eq!(bin_of(&e, 0.0), Some(0));
    assert_eq!(bin_of(&e, 1.0), Some(1));
    assert_eq!(bin_of(&e, 2.0), Some(1), "last bin closed");
    assert_eq!(bin_of(&e, 2.0000001), None);
    assert_eq!(bin_of(&e, -0.0), Some(0));
    assert_eq!(bin_of(&e, f64::NAN), None);
}

#[test]
fn moments_merge_equals_one_stream() {
    let xs: Vec<f64> = (0..1000)
        .map(|k| to_unit_f64(hash4(1, k, 0, 0)) * 2.0 - 1.0)
        .collect();
    let mut one = Moments::default();
    xs.iter().for_each(|x| one.push(*x));
    let mut merged = Moments::default();
    for c in xs.chunks(77) {
        let mut m = Moments::default();
        c.iter().for_each(|x| m.push(*x));
        merged.merge(&m);
    }
    assert_eq!(merged.count, 1000);
    assert!((merged.mean - one.mean).abs() < 1e-15);
    assert!((merged.m2 - one.m2).abs() < 1e-12 * one.m2);
}

#[test]
fn traced_maps_equal_records_and_are_thread_independent() {
    let scene = scenes::load("dynamics", 1.0, 0).unwrap().scene;
    let pts = surface_points(&scene, None, 300, 11);
    let (p, n): (Vec<Vec3>, Vec<Vec3>) = pts.iter().copied().unzip();
    let mut calls = Vec::new();
    let a = VisibilityMaps::trace(&scene, &p, &n, 4, Some(1), &mut |d, t| {
        calls.push((d, t));
        true
    })
    .unwrap();
    assert_eq!(calls, vec![(300, 300)]);
    let b = VisibilityMaps::trace(&scene, &p, &n, 4, Some(2), &mut |_, _| true).unwrap();
    assert_eq!(a, b);
    let pattern = default_pattern(4).unwrap();
    for i in (0..300).step_by(37) {
        let (rec, _) = Record::trace(&scene, p[i], n[i], pattern, 0).unwrap();
        assert_eq!(a.map(i), rec.bits.view().bit_words());
        assert_eq!(a.popcount(i), rec.bits.popcount());
    }
    // Some maps are partly visible, so ρ is defined for them.
    assert!((0..300).any(|i| a.popcount(i) > 0 && (a.popcount(i) as u64) < a.directions()));

    let stop = VisibilityMaps::trace(&scene, &p, &n, 4, Some(1), &mut |_, _| false);
    assert!(matches!(stop, Err(Error::InvalidArgument { ref name, .. }) if name == "progress"));
}

#[test]
fn sampled_pairs_are_nearest_neighbours_then_far_draws() {
    let (_, maps) = random_maps(400, 2, 9);
    let pts = maps.points();
    let s = PairSampling {
        neighbours: 5,
        far: 7,
        far_min: 0.05,
        far_max: 3.0,
        seed: 4,
    };
    let pairs = sample_pairs(&maps, &s, Some(1)).unwrap();
    assert_eq!(pairs, sample_pairs(&maps, &s, Some(2)).unwrap());
    assert!(pairs.iter().all(|p| p[0] != p[1]));
    assert!(pairs.len() <= 400 * 12 && pairs.len() >= 400 * 5);
    // Each point's first five partners are its five nearest by brute force.
    let mut k = 0;
    for i in 0..400 {
        let mut d: Vec<(f32, usize)> = (0..400)
            .filter(|&j| j != i)
            .map(|j| (pts[i].distance_squared(pts[j]), j))
            .collect();
        d.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let mine: Vec<usize> = pairs[k..k + 5].iter().map(|p| p[1] as usize).collect();
        for (r, j) in mine.iter().enumerate() {
            assert_eq!(pairs[k + r][0] as usize, i);
            assert_eq!(
                pts[i].distance_squared(pts[*j]),
                d[r].0,
                "point {i} rank {r}"
            );
        }
        k += 5;
        while k < pairs.len() && pairs[k][0] as usize == i {
            k += 1;
        }
    }
    assert_eq!(k, pairs.len());
    let other = sample_pairs(&maps, &PairSampling { seed: 5, ..s }, Some(1)).unwrap();
    assert_ne!(pairs, other, "the seed changes the far draws");
}

#[test]
fn local_correlation_equals_a_plain_loop() {
    let (_, maps) = random_maps(300, 3, 21);
    let (mean, count) = local_correlation(&maps, 0.8, 30.0, Some(2)).unwrap();
    let (mean1, count1) = local_correlation(&maps, 0.8, 30.0, Some(1)).unwrap();
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(
        (bits(&mean), &count),
        (bits(&mean1), &count1),
        "1 vs 2 threads"
    );
    let mut some = 0;
    for i in 0..maps.len() {
        let rs: Vec<f64> = (0..maps.len())
            .filter(|&j| j != i)
            .filter(|&j| {
                let (d, t) = maps.distance_angle(i, j);
                d <= 0.8 && t < 30.0
            })
            .filter_map(|j| maps.rho(i, j))
            .collect();
        assert_eq!(count[i] as usize, rs.len(), "point {i}");
        if rs.is_empty() {
            assert!(mean[i].is_nan());
        } else {
            some += 1;
            let m = rs.iter().sum::<f64>() / rs.len() as f64;
            assert!((mean[i] - m).abs() < 1e-13, "point {i}: {} vs {m}", mean[i]);
        }
    }
    assert!(some > 100);
}

#[test]
fn bad_arguments_name_themselves() {
    let name_of = |e: Error| match e {
        Error::InvalidArgument { name, .. } => name,
        other => panic!("{other}"),
    };
    let (_, maps) = random_maps(10, 2, 1);
    let de = [0.0, 1.0];
    let te = [0.0, 90.0];
    let bins = |d: &[f64], t: &[f64]| correlation_bins(&maps, Pairs::All, d, t, None);
    assert_eq!(name_of(bins(&[0.0], &te).unwrap_err()), "distance_edges");
    assert_eq!(
        name_of(bins(&[1.0, 0.5], &te).unwrap_err()),
        "distance_edges"
    );
    assert_eq!(
        name_of(bins(&[-1.0, 0.5], &te).unwrap_err()),
        "distance_edges"
    );
    assert_eq!(
        name_of(bins(&[0.0, f64::NAN], &te).unwrap_err()),
        "distance_edges"
    );
    assert_eq!(
        name_of(bins(&de, &[0.0, 181.0]).unwrap_err()),
        "theta_edges"
    );
    assert_eq!(name_of(bins(&de, &[0.0, 0.0]).unwrap_err()), "theta_edges");
    let bad = [[0u32, 10]];
    let e = correlation_bins(&maps, Pairs::List(&bad), &de, &te, None).unwrap_err();
    assert_eq!(name_of(e), "pairs");
    let e = correlation_bins(&maps, Pairs::All, &de, &te, Some(0)).unwrap_err();
    assert_eq!(name_of(e), "threads");

    let p = vec![Vec3::ZERO; 3];
    let n = vec![Vec3::Y; 3];
    let mk = |p: Vec<Vec3>, n: Vec<Vec3>, w: usize| {
        VisibilityMaps::from_bit_words(2, vec![0; w], p, n).map(|_| ())
    };
    assert!(mk(p.clone(), n.clone(), 3).is_ok());
    assert_eq!(name_of(mk(vec![], vec![], 0).unwrap_err()), "points");
    assert_eq!(
        name_of(mk(p.clone(), n[..2].to_vec(), 3).unwrap_err()),
        "normals"
    );
    let mut nan = p.clone();
    nan[1].y = f32::NAN;
    assert_eq!(
        name_of(mk(nan.clone(), n.clone(), 3).unwrap_err()),
        "points"
    );
    let mut zero = n.clone();
    zero[2] = Vec3::ZERO;
    assert_eq!(name_of(mk(p.clone(), zero, 3).unwrap_err()), "normals");
    assert_eq!(name_of(mk(p.clone(), n.clone(), 2).unwrap_err()), "words");
    let e = VisibilityMaps::from_bit_words(2, vec![1 << 16, 0, 0], p.clone(), n.clone());
    assert_eq!(name_of(e.unwrap_err()), "words");
    let e = VisibilityMaps::from_bit_words(8, vec![0; 3], p.clone(), n.clone());
    assert!(e.is_err());

    let scene = scenes::load("cornell", 1.0, 0).unwrap().scene;
    let e = VisibilityMaps::trace(&scene, &nan, &n, 3, None, &mut |_, _| true).unwrap_err();
    assert_eq!(name_of(e), "points");
    let e = VisibilityMaps::trace(&scene, &p, &n, 0, None, &mut |_, _| true);
    assert!(e.is_err());

    let s = PairSampling {
        neighbours: 2,
        far: 2,
        far_min: 0.1,
        far_max: 1.0,
        seed: 0,
    };
    let dup = VisibilityMaps::from_bit_words(2, vec![0; 3], p.clone(), n.clone()).unwrap();
    let one = VisibilityMaps::from_bit_words(2, vec![0; 1], p[..1].to_vec(), n[..1].to_vec());
    let pairs = |m: &VisibilityMaps, s: PairSampling| sample_pairs(m, &s, None).map(|_| ());
    assert_eq!(name_of(pairs(&one.unwrap(), s).unwrap_err()), "points");
    let p = &dup;
    let with = |f: &dyn Fn(&mut PairSampling)| {
        let mut t = s;
        f(&mut t);
        t
    };
    assert_eq!(
        name_of(pairs(p, with(&|t| t.far_min = 0.0)).unwrap_err()),
        "far_min"
    );
    assert_eq!(
        name_of(pairs(p, with(&|t| t.far_max = 0.05)).unwrap_err()),
        "far_max"
    );
    assert_eq!(
        name_of(pairs(p, with(&|t| t.far_max = f32::INFINITY)).unwrap_err()),
        "far_max"
    );
    assert_eq!(
        name_of(pairs(p, with(&|t| t.neighbours = 5000)).unwrap_err()),
        "neighbours"
    );
    assert_eq!(
        name_of(pairs(p, with(&|t| t.far = 5000)).unwrap_err()),
        "far"
    );
    assert!(pairs(p, s).is_ok(), "duplicate points are fine");

    assert_eq!(
        name_of(local_correlation(&maps, -1.0, 10.0, None).unwrap_err()),
        "d_max"
    );
    assert_eq!(
        name_of(local_correlation(&maps, 1.0, 0.0, None).unwrap_err()),
        "theta_max_deg"
    );
}
