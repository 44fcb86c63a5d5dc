//! Reach and radius queries against brute force over every record, on uniform, clustered
//! and planar sets with shared positions and radii of 0, ∞, NaN and everything between;
//! through growth, rebuilds and radii changed behind the index's back; and the coverage
//! test's rules.

use glam::Vec3;

use super::*;
use crate::error::Result;
use crate::sampling::rng::{hash4, to_unit_f32};
use crate::spatial::{Records, SpatialIndex};

fn unit(seed: u64, k: u64) -> f32 {
    to_unit_f32(hash4(seed, k, 0, 11))
}

/// Records with a position, a normal (unused here) and a radius.
#[derive(Clone, Debug, Default)]
struct Sites {
    position: Vec<Vec3>,
    radius: Vec<f32>,
}

impl Records for Sites {
    fn len(&self) -> usize {
        self.position.len()
    }

    fn site(&self, id: usize) -> (Vec3, Vec3) {
        (self.position[id], Vec3::Y)
    }

    fn radius(&self, id: usize) -> f32 {
        self.radius[id]
    }
}

impl Sites {
    fn push(&mut self, p: Vec3, r: f32) -> Result<usize> {
        self.position.push(p);
        self.radius.push(r);
        Ok(self.position.len() - 1)
    }
}

#[derive(Clone, Copy, Debug)]
enum Layout {
    /// Uniform in the unit cube.
    Uniform,
    /// Eight tight clusters (width 1e-3) in the unit cube.
    Clustered,
    /// The unit square of the floor y = 0, on a grid of step 1/64 half the time.
    Floor,
}

/// `count` positions in `layout`; about one in eight repeats an earlier one exactly when
/// `shared` (the index chains those), else all are distinct (then the index answers from
/// its lane bounds alone until radii change).
fn positions(layout: Layout, count: usize, seed: u64, shared: bool) -> Vec<Vec3> {
    let mut out: Vec<Vec3> = Vec::with_capacity(count);
    let mut seen = std::collections::HashSet::new();
    for k in 0..count as u64 {
        let u = |d: u64| unit(seed, 4 * k + d);
        if shared && k > 0 && hash4(seed, k, 1, 0).is_multiple_of(8) {
            out.push(out[(hash4(seed, k, 2, 0) % k) as usize]);
            continue;
        }
        out.push(match layout {
            Layout::Uniform => Vec3::new(u(0), u(1), u(2)),
            Layout::Clustered => {
                let c = (hash4(seed, k, 3, 0) % 8) as f32;
                let centre = Vec3::new(c * 0.11, (c * 0.37).fract(), (c * 0.71).fract());
                centre + 1e-3 * Vec3::new(u(0), u(1), u(2))
            }
            Layout::Floor if k % 2 == 0 => {
                let g = |v: f32| (v * 64.0).floor() / 64.0;
                Vec3::new(g(u(0)), 0.0, g(u(1)))
            }
            Layout::Floor => Vec3::new(u(0), 0.0, u(1)),
        });
        if !shared && !seen.insert(out[out.len() - 1].to_array().map(f32::to_bits)) {
            // A grid point taken already: one off the grid instead.
            let p = out.len() - 1;
            out[p] += Vec3::new(1e-4 * u(2), 0.0, 1e-4 * u(3));
            assert!(seen.insert(out[p].to_array().map(f32::to_bits)));
        }
    }
    out
}

/// A radius for record `k`: 0, ∞, NaN, negative, or spread over four decades around
/// `scale` (the typical spacing of the records).
fn radius(seed: u64, k: u64, scale: f32) -> f32 {
    match hash4(seed, k, 5, 0) % 16 {
        0 => 0.0,
        1 => f32::INFINITY,
        2 => f32::NAN,
        3 => -scale,
        _ => scale * 10f32.powf(4.0 * unit(seed + 1, k) - 2.0),
    }
}

/// Every record covering `x`, one by one: the definition.
fn brute_reach(sites: &Sites, x: Vec3) -> Vec<(u32, f32)> {
    (0..sites.len())
        .filter_map(|i| {
            let d2 = distance2(sites.position[i], x);
            reaches(d2, sites.radius[i]).then_some((i as u32, d2))
        })
        .collect()
}

fn brute_radius(sites: &Sites, x: Vec3, r: f32) -> Vec<(u32, f32)> {
    (0..sites.len())
        .filter_map(|i| {
            let d2 = distance2(sites.position[i], x);
            reaches(d2, r).then_some((i as u32, d2))
        })
        .collect()
}

fn bits(v: &[(u32, f32)]) -> Vec<(u32, u32)> {
    v.iter().map(|&(id, d2)| (id, d2.to_bits())).collect()
}

/// Query points: at records (where records sharing the position have d = 0), near them,
/// and anywhere in and around the unit cube.
fn queries(sites: &Sites, count: u64, seed: u64) -> Vec<Vec3> {
    (0..count)
        .map(|q| {
            let any = Vec3::new(
                unit(seed, 3 * q),
                unit(seed, 3 * q + 1),
                unit(seed, 3 * q + 2),
            );
            match q % 3 {
                0 if !sites.is_empty() => sites.position[q as usize % sites.len()],
                1 if !sites.is_empty() => sites.position[q as usize % sites.len()] + 1e-3 * any,
                _ => 1.4 * any - 0.2,
            }
        })
        .collect()
}

/// Checks both queries against brute force at `points`; returns the records found.
fn check(index: &SpatialIndex<Sites>, points: &[Vec3], what: &str) -> usize {
    let sites = index.records();
    let mut out = Vec::new();
    let mut found = 0;
    for (q, &x) in points.iter().enumerate() {
        out.clear();
        index.within_reach(x, &mut out);
        let want = brute_reach(sites, x);
        assert_eq!(bits(&out), bits(&want), "{what}: reach at {x}");
        found += out.len();
        let r = [0.0, 1e-3, 0.05, 0.3, f32::INFINITY, f32::NAN, -1.0][q % 7];
        out.clear();
        index.within_radius(x, r, &mut out);
        assert_eq!(
            bits(&out),
            bits(&brute_radius(sites, x, r)),
            "{what}: radius {r} at {x}"
        );
    }
    found
}

#[test]
fn reach_queries_find_exactly_the_records_that_cover_the_point() {
    let mut found = 0;
    for (layout, shared) in [Layout::Uniform, Layout::Clustered, Layout::Floor]
        .into_iter()
        .flat_map(|l| [(l, true), (l, false)])
    {
        for (count, seed) in [
            (1usize, 1u64),
            (2, 2),
            (33, 3),
            (500, 4),
            (3000, 5),
            (10_000, 6),
        ] {
            // Radii around the spacing of the records: each point is covered by a few.
            let scale = match layout {
                Layout::Floor => (1.0 / count as f32).sqrt(),
                _ => (1.0 / count as f32).cbrt(),
            };
            let mut sites = Sites::default();
            for (k, p) in positions(layout, count, seed, shared)
                .into_iter()
                .enumerate()
            {
                sites.push(p, radius(seed, k as u64, scale)).unwrap();
            }
            // Grown one record at a time (bounds raised along each descent), and built
            // balanced at once.
            let mut grown = SpatialIndex::new(Sites::default());
            for k in 0..count {
                let (p, r) = (sites.position[k], sites.radius[k]);
                grown.admit(|s| s.push(p, r)).unwrap();
            }
            let built = SpatialIndex::new(sites.clone());
            let points = queries(&sites, 150, seed + 100);
            let what = format!("{layout:?}, {count} records, shared {shared}");
            found += check(&grown, &points, &format!("grown, {what}"));
            found += check(&built, &points, &format!("built, {what}"));
        }
    }
    // Not a vacuous comparison: infinite radii alone give 1/16 of every set per query.
    assert!(found > 200_000, "{found} records found");
}

#[test]
fn radii_lowered_behind_the_index_keep_answers_exact_and_refresh_tightens() {
    for (layout, shared) in [(Layout::Uniform, true), (Layout::Floor, false)] {
        let count = 4000;
        let mut index = SpatialIndex::new(Sites::default());
        for (k, p) in positions(layout, count, 7, shared).into_iter().enumerate() {
            // Large radii to begin with, as before the irradiance cache clamps them.
            let r = if k % 5 == 0 { f32::INFINITY } else { 0.3 };
            index.admit(|s| s.push(p, r)).unwrap();
        }
        let points = queries(index.records(), 120, 8);
        // Lower every radius (infinite ones too, some to 0 or NaN): the tree's bounds are
        // now loose but the answers must not change from brute force.
        for (k, r) in index.records_mut().radius.iter_mut().enumerate() {
            *r = match k % 7 {
                0 => 0.0,
                1 => f32::NAN,
                _ => r.min(0.3) * unit(9, k as u64),
            };
        }
        check(&index, &points, &format!("{layout:?}, lowered"));
        index.refresh_reach();
        check(&index, &points, &format!("{layout:?}, refreshed"));
        // Raised behind the index and refreshed: exact again.
        for (k, r) in index.records_mut().radius.iter_mut().enumerate() {
            if k % 3 == 0 {
                *r = 0.5 * unit(10, k as u64);
            }
        }
        index.refresh_reach();
        check(
            &index,
            &points,
            &format!("{layout:?}, raised and refreshed"),
        );
        // Growth after a refresh raises the refreshed bounds.
        for (k, p) in positions(layout, 300, 11, shared).into_iter().enumerate() {
            index
                .admit(|s| s.push(p, radius(12, k as u64, 0.05)))
                .unwrap();
        }
        check(&index, &points, &format!("{layout:?}, grown after refresh"));
    }
}

#[test]
fn rebuilds_after_removals_and_new_radii_answer_exactly() {
    let mut index = SpatialIndex::new(Sites::default());
    for (k, p) in positions(Layout::Clustered, 3000, 13, true)
        .into_iter()
        .enumerate()
    {
        index
            .admit(|s| s.push(p, radius(13, k as u64, 0.01)))
            .unwrap();
    }
    let points = queries(index.records(), 150, 14);
    check(&index, &points, "before the rebuild");
    index.rebuild(|s| {
        // Remove every third record (chains change heads) and grow some radii.
        let keep: Vec<usize> = (0..s.len()).filter(|k| k % 3 != 1).collect();
        s.position = keep.iter().map(|&k| s.position[k]).collect();
        s.radius = keep
            .iter()
            .map(|&k| if k % 4 == 0 { 0.05 } else { s.radius[k] })
            .collect();
    });
    check(&index, &points, "after the rebuild");
    for (k, p) in positions(Layout::Uniform, 500, 15, true)
        .into_iter()
        .enumerate()
    {
        index
            .admit(|s| s.push(p, radius(15, k as u64, 0.1)))
            .unwrap();
    }
    check(&index, &points, "grown after the rebuild");
}

#[test]
fn empty_indexes_and_non_finite_points_find_nothing_and_out_is_appended_to() {
    let empty = SpatialIndex::new(Sites::default());
    let mut out = vec![(7u32, 1.0f32)];
    empty.within_reach(Vec3::ZERO, &mut out);
    empty.within_radius(Vec3::ZERO, f32::INFINITY, &mut out);
    assert_eq!(out, vec![(7, 1.0)]);

    let mut sites = Sites::default();
    sites.push(Vec3::new(1.0, 0.0, 0.0), f32::INFINITY).unwrap();
    sites.push(Vec3::ZERO, 2.0).unwrap();
    sites.push(Vec3::ZERO, 0.5).unwrap();
    let index = SpatialIndex::new(sites);
    for x in [
        Vec3::NAN,
        Vec3::new(f32::INFINITY, 0.0, 0.0),
        Vec3::splat(f32::NEG_INFINITY),
    ] {
        index.within_reach(x, &mut out);
        index.within_radius(x, f32::INFINITY, &mut out);
    }
    assert_eq!(out, vec![(7, 1.0)]);
    // Appended after what `out` holds, sorted by id among themselves; of the two records
    // at the origin, the chained one (radius 0.5) has the point exactly on its border.
    index.within_reach(Vec3::new(0.5, 0.0, 0.0), &mut out);
    assert_eq!(out, vec![(7, 1.0), (0, 0.25), (1, 0.25)]);
    out.clear();
    // Strict: at distance exactly 2 the record of radius 2 does not reach.
    index.within_reach(Vec3::new(0.0, 2.0, 0.0), &mut out);
    assert_eq!(out, vec![(0, 5.0)]);
}

/// Queries walking in small steps (pixel order) are served from wide gatherings and
/// answer exactly as brute force, also when the index changes mid-walk (a record admitted
/// next to the walk, radii lowered, raised and refreshed): each change must end the
/// gathered set's use.
#[test]
fn walks_served_from_gathered_sets_answer_exactly_through_changes() {
    for (layout, shared) in [
        (Layout::Floor, false),
        (Layout::Uniform, true),
        (Layout::Clustered, false),
    ] {
        let count = 5000;
        let scale = match layout {
            Layout::Floor => (1.0 / count as f32).sqrt(),
            _ => (1.0 / count as f32).cbrt(),
        };
        let mut index = SpatialIndex::new(Sites::default());
        for (k, p) in positions(layout, count, 17, shared).into_iter().enumerate() {
            let r = match k % 50 {
                0 => f32::INFINITY,
                1 => 0.0,
                _ => scale * (0.5 + 3.0 * unit(18, k as u64)),
            };
            index.admit(|s| s.push(p, r)).unwrap();
        }
        let gathers = || with_reach_scratch(|s| s.gathers);
        let (mut queries, before) = (0u64, gathers());
        let mut out = Vec::new();
        for row in 0..24u64 {
            let start = Vec3::new(
                unit(19, 3 * row),
                unit(19, 3 * row + 1),
                unit(19, 3 * row + 2),
            );
            let start = if matches!(layout, Layout::Floor) {
                start * Vec3::new(1.0, 0.0, 1.0)
            } else {
                start
            };
            let heading = Vec3::new(1.0, 0.0, unit(20, row) - 0.5).normalize();
            for k in 0..150u64 {
                let x = start + heading * (k as f32 * 0.2 * scale);
                match (row % 4, k) {
                    // A record right at the walk's next point, reaching it.
                    (0, 75) => {
                        index
                            .admit(|s| s.push(x + 0.01 * scale, 0.1 * scale))
                            .unwrap();
                    }
                    // Radii lowered behind the tree (some to 0).
                    (1, 75) => {
                        for (i, r) in index.records_mut().radius.iter_mut().enumerate() {
                            if i % 3 == 0 {
                                *r *= 0.5 * (i % 2) as f32;
                            }
                        }
                    }
                    // Radii raised, then the bounds refreshed.
                    (2, 75) => {
                        for (i, r) in index.records_mut().radius.iter_mut().enumerate() {
                            if i % 5 == 0 {
                                *r = 2.0 * r.max(scale);
                            }
                        }
                        index.refresh_reach();
                    }
                    _ => {}
                }
                out.clear();
                index.within_reach(x, &mut out);
                assert_eq!(
                    bits(&out),
                    bits(&brute_reach(index.records(), x)),
                    "{layout:?}, row {row}, step {k}"
                );
                queries += 1;
            }
        }
        // The walk was served from wide gatherings, not one gathering per query.
        let gathered = gathers() - before;
        assert!(
            gathered * 3 < queries,
            "{layout:?}: {gathered} gatherings for {queries} queries"
        );
    }
}

#[test]
fn radix_and_comparison_sorts_agree() {
    let mut spare = Vec::new();
    for (n, largest) in [
        (0usize, 10u32),
        (5, 10),
        (63, 1000),
        (64, 100),
        (700, 100_000),
        (3000, u32::MAX),
    ] {
        let mut keys: Vec<u32> = Vec::new();
        let mut seen = std::collections::HashSet::new();
        let mut k = 0u64;
        while keys.len() < n {
            let key = (hash4(21, k, n as u64, 0) % (largest as u64 + 1)) as u32;
            k += 1;
            if seen.insert(key) {
                keys.push(key);
            }
        }
        let mut items: Vec<(u32, f32)> = keys.iter().map(|&id| (id, id as f32)).collect();
        let mut want = items.clone();
        want.sort_unstable_by_key(|&(id, _)| id);
        sort_by_key(&mut items, &mut spare, |&(id, _)| id);
        assert_eq!(items, want, "{n} keys up to {largest}");
    }
}

/// Small reaches visit few leaves: the bounds prune (brute-force equality alone would
/// pass without them). Records on a 100x100 grid of step 1 with radius 0.5: a point is
/// covered by at most one and its neighbourhood spans a leaf or few, of 313 or more.
#[test]
fn reach_bounds_prune_the_tree() {
    let mut index = SpatialIndex::new(Sites::default());
    for k in 0..10_000u32 {
        let p = Vec3::new((k % 100) as f32, 0.0, (k / 100) as f32);
        index.admit(|s| s.push(p, 0.5)).unwrap();
    }
    let mut out = Vec::new();
    let mut most = 0;
    for q in 0..500u64 {
        let x = Vec3::new(99.0 * unit(16, 2 * q), 0.0, 99.0 * unit(16, 2 * q + 1));
        out.clear();
        index.within_reach(x, &mut out);
        assert!(out.len() <= 1);
        let visited = with_reach_scratch(|s| s.reach.leaves_visited());
        most = most.max(visited);
    }
    assert!(most <= 4, "{most} leaves visited");
}

#[test]
fn reach_factor_and_coverage_follow_their_rules() {
    assert_eq!(reach_factor(0.0, f32::INFINITY), 1.0);
    assert_eq!(reach_factor(1e30, f32::INFINITY), 1.0);
    assert_eq!(reach_factor(0.0, f32::NAN), 1.0);
    // No reach covers nothing, its own point included.
    assert_eq!(reach_factor(0.0, 0.0), 0.0);
    assert_eq!(reach_factor(2.0, 2.0), 0.0);
    assert_eq!(reach_factor(3.0, 2.0), 0.0);
    assert_eq!(reach_factor(0.5, 2.0), 0.75);
    assert_eq!(reach_factor(0.0, 2.0), 1.0);
    assert_eq!(coverage([]), 0.0);
    assert_eq!(
        coverage([(0.9, 1.0, 2.0), (0.6, 0.0, f32::INFINITY), (1.0, 3.0, 2.0)]),
        0.6
    );
    assert_eq!(coverage([(0.9, 0.5, 2.0), (0.6, 0.0, 0.0)]), 0.9 * 0.75);
}
