//! The `m`-nearest query under each metric against a linear scan, and eq. 6.3's normal
//! term deciding between a near record turned away and a farther one facing alike.

use glam::Vec3;

use super::*;
use crate::error::Result;
use crate::sampling::rng::{hash4, to_unit_f32};
use crate::spatial::{with_thread_scratch, Records, SpatialIndex, Weighting};

fn unit(seed: u64, k: u64) -> f32 {
    to_unit_f32(hash4(seed, k, 0, 13))
}

fn random_dir(seed: u64, k: u64) -> Vec3 {
    let z = 2.0 * unit(seed, 2 * k) - 1.0;
    let phi = std::f32::consts::TAU * unit(seed, 2 * k + 1);
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Records with a position and a normal.
#[derive(Clone, Debug, Default)]
struct Sites {
    position: Vec<Vec3>,
    normal: Vec<Vec3>,
}

impl Records for Sites {
    fn len(&self) -> usize {
        self.position.len()
    }

    fn site(&self, id: usize) -> (Vec3, Vec3) {
        (self.position[id], self.normal[id])
    }
}

fn index(sites: &[(Vec3, Vec3)]) -> SpatialIndex<Sites> {
    let mut index = SpatialIndex::new(Sites::default());
    for &(p, n) in sites {
        index
            .admit(|s: &mut Sites| -> Result<usize> {
                s.position.push(p);
                s.normal.push(n);
                Ok(s.position.len() - 1)
            })
            .unwrap();
    }
    index
}

fn weighting(m: usize, theta_max: f32, metric: Metric) -> Weighting {
    Weighting {
        m,
        theta_max,
        w_lo: 0.0,
        lambda: 0.0,
        metric,
    }
}

/// The ids the query keeps, with the metric of each from the formula.
fn query(index: &SpatialIndex<Sites>, w: &Weighting, x: Vec3, n: Vec3, d_max: f32) -> Vec<u32> {
    with_thread_scratch(|scratch| {
        let hits = index.m_nearest(w, x, n, d_max, scratch);
        (0..hits.len).map(|i| hits.id(i)).collect()
    })
}

/// 2000 records with random normals in the unit cube, 300 lookups each under squared
/// distance and eq. 6.3 with three λ: the kept records are `min(m, in range)` of them,
/// all in range, and none left out ranks below one kept (beyond rounding of the
/// distances' summation order, 1e-5).
#[test]
fn the_query_keeps_the_m_least_under_its_metric() {
    let sites: Vec<(Vec3, Vec3)> = (0..2000)
        .map(|k| {
            let p = Vec3::new(unit(1, 3 * k), unit(1, 3 * k + 1), unit(1, 3 * k + 2));
            (p, random_dir(2, k))
        })
        .collect();
    let idx = index(&sites);
    let metrics = [
        Metric::SquaredDistance,
        Metric::DistanceNormal { lambda: 0.0 },
        Metric::DistanceNormal { lambda: 0.05 },
        Metric::DistanceNormal { lambda: 1.0 },
    ];
    let (mut reordered, mut total) = (0, 0);
    for (mi, &metric) in metrics.iter().enumerate() {
        for q in 0..300u64 {
            let x = Vec3::new(unit(3, 3 * q), unit(3, 3 * q + 1), unit(3, 3 * q + 2));
            let n = random_dir(4, q);
            let (m, theta_max, d_max) = (1 + (q % 12) as usize, 1.0 + 2.0 * unit(5, q), 0.15);
            let w = weighting(m, theta_max, metric);
            let got = query(&idx, &w, x, n, d_max);
            let in_range: Vec<u32> = (0..sites.len() as u32)
                .filter(|&i| {
                    let (p, nn) = sites[i as usize];
                    p.distance_squared(x) <= d_max * d_max
                        && (n.dot(nn).clamp(-1.0, 1.0) as f64).acos() < theta_max as f64 - 1e-4
                })
                .collect();
            let key = |i: u32| {
                let (p, nn) = sites[i as usize];
                metric.between(x, n, p, nn)
            };
            assert!(got.len() <= m, "{metric:?} {q}");
            assert!(got.len() >= m.min(in_range.len()), "{metric:?} {q}");
            let worst_kept = got.iter().map(|&i| key(i)).fold(0.0f32, f32::max);
            for &i in &in_range {
                if !got.contains(&i) {
                    assert!(
                        key(i) >= worst_kept - 1e-5,
                        "{metric:?} q {q}: {i} left out"
                    );
                }
            }
            for &i in &got {
                assert!(sites[i as usize].0.distance_squared(x) <= d_max * d_max * (1.0 + 1e-5));
            }
            // How often the normal term changed which records are kept.
            if mi == 3 {
                let by_d2 = query(
                    &idx,
                    &weighting(m, theta_max, Metric::SquaredDistance),
                    x,
                    n,
                    d_max,
                );
                let (mut a, mut b) = (got.clone(), by_d2);
                a.sort_unstable();
                b.sort_unstable();
                reordered += (a != b) as u32;
                total += 1;
            }
        }
    }
    // λ = 1 in a ball of 0.15: the normal term decides most lookups' sets.
    assert!(reordered > total / 2, "{reordered} of {total}");
}

/// A record 0.01 away whose normal is turned by 90° against one 0.05 away facing alike:
/// by distance the near one comes first; by eq. 6.3 with λ = 0.1 (0.01 + 0.1 > 0.05) the
/// far one; with λ = 0.02 (0.01 + 0.02 < 0.05) the near one again.
#[test]
fn the_normal_term_outranks_distance_by_lambda() {
    let x = Vec3::ZERO;
    let n = Vec3::Y;
    let near = (Vec3::new(0.01, 0.0, 0.0), Vec3::X);
    let far = (Vec3::new(0.0, 0.0, 0.05), Vec3::Y);
    let idx = index(&[near, far]);
    let theta_max = std::f32::consts::PI;
    let one = |metric| query(&idx, &weighting(1, theta_max, metric), x, n, 1.0);
    assert_eq!(one(Metric::SquaredDistance), vec![0]);
    assert_eq!(one(Metric::DistanceNormal { lambda: 0.1 }), vec![1]);
    assert_eq!(one(Metric::DistanceNormal { lambda: 0.02 }), vec![0]);
    assert!(
        (Metric::DistanceNormal { lambda: 0.1 }.between(x, n, near.0, near.1) - 0.11).abs() < 1e-6
    );
    assert!(Metric::DistanceNormal { lambda: 0.0 }.is_valid());
    for lambda in [-1.0, f32::NAN, f32::INFINITY] {
        assert!(!Metric::DistanceNormal { lambda }.is_valid());
    }
}
