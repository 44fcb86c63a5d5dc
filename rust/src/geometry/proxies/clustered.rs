//! General proxies by vertex clustering (BLD §5, the nature and forest scenes: "the
//! vertices of the triangles are clustered in a grid, where the cells have a size equal to
//! 3% of the size of the bounding box of the model"; Rossignac & Borrel 1993).
//!
//! Each vertex moves to its cell's representative, the mean of the triangle corners in the
//! cell; triangles whose three corners fall in fewer than three cells vanish, and of
//! triangles with the same three cells in the same orientation one is kept. Cells are
//! cubes of side `cell` times the object's largest box side, anchored at the box's
//! minimum. The result has no guarantee (kind general).
//!
//! Why not quadric edge collapse through the `meshopt` crate: it compiles meshoptimizer's
//! C++ sources with `cc` (a C++ toolchain in every build, ~1 min on this machine's shared
//! cores) for a simplifier that needs indexed, welded meshes and keeps topology, which a
//! hairball's thousands of tubes defeat at low targets; clustering is the paper's method,
//! linear in the triangles and a few lines.

use glam::{DVec3, Vec3};

use super::inscribed::{weld, Mix, MixMap, Welded};
use super::{per_object, ProxyKind, ProxySet};
use crate::error::{Error, Result};
use crate::geometry::{Bounds, Scene};

/// Finest cell `clustered_to` tries, as a fraction of the box.
const FINEST: f32 = 1e-4;

impl ProxySet {
    /// General proxies by vertex clustering with cells of `cell` (in (0, 1]) times each
    /// object's largest box side (see the module docs). Errors name `cell` and `objects`.
    pub fn clustered(parent: &Scene, objects: Option<&[u32]>, cell: f32) -> Result<Self> {
        check_cell(cell)?;
        per_object(parent, objects, ProxyKind::General, |_, triangles| {
            Ok(cluster(triangles, cell))
        })
    }

    /// General proxies by vertex clustering, per object the finest cell (found by
    /// bisection between `1e-4` and 1 of the box, 14 steps) whose proxy has at most
    /// `target` (>= 1) triangles; an object of at most `target` triangles stands for
    /// itself. The coarsest clustering (one cell side per box) may still exceed a tiny
    /// target; it is kept then. Errors name `target` and `objects`.
    pub fn clustered_to(parent: &Scene, objects: Option<&[u32]>, target: usize) -> Result<Self> {
        if target == 0 {
            return Err(Error::invalid(
                "target",
                "must be at least 1 triangle, got 0",
            ));
        }
        per_object(parent, objects, ProxyKind::General, |_, triangles| {
            if triangles.len() <= target {
                return Ok((!triangles.is_empty()).then(|| triangles.to_vec()));
            }
            let welded = weld(triangles);
            let bounds = Bounds::of_triangles(triangles);
            let (mut fine, mut coarse) = (FINEST.ln(), 0.0f32);
            let mut best = cluster_welded(&welded, &bounds, 1.0);
            for _ in 0..14 {
                let mid = 0.5 * (fine + coarse);
                let got = cluster_welded(&welded, &bounds, mid.exp());
                if got.as_ref().map_or(0, Vec::len) <= target {
                    best = got;
                    coarse = mid;
                } else {
                    fine = mid;
                }
            }
            Ok(best)
        })
    }
}

/// Fails, naming `cell`, unless `0 < cell <= 1`.
pub(crate) fn check_cell(cell: f32) -> Result<()> {
    if cell > 0.0 && cell <= 1.0 {
        Ok(())
    } else {
        Err(Error::invalid(
            "cell",
            format!("must be a fraction of the object's box in (0, 1], got {cell}"),
        ))
    }
}

/// The clustered triangles of one object (see the module docs); `None` when nothing is
/// left.
pub(crate) fn cluster(triangles: &[[Vec3; 3]], cell: f32) -> Option<Vec<[Vec3; 3]>> {
    let b = Bounds::of_triangles(triangles);
    let side = b.extent() as f64 * cell as f64;
    if b.is_empty() || side <= 0.0 {
        return None;
    }
    let lo = b.min.as_dvec3();
    let mut cells: MixMap<[u32; 3], u32> = MixMap::default();
    let mut sums: Vec<(DVec3, u32)> = Vec::new();
    let ids: Vec<[u32; 3]> = triangles
        .iter()
        .map(|t| {
            t.map(|v| {
                let id = *cells.entry(cell_key(v, lo, side)).or_insert_with(|| {
                    sums.push((DVec3::ZERO, 0));
                    sums.len() as u32 - 1
                });
                let s = &mut sums[id as usize];
                s.0 += v.as_dvec3();
                s.1 += 1;
                id
            })
        })
        .collect();
    assemble(ids.into_iter(), &sums)
}

/// The cell of `v` for cells of side `side` anchored at `lo`.
fn cell_key(v: Vec3, lo: DVec3, side: f64) -> [u32; 3] {
    ((v.as_dvec3() - lo) / side)
        .floor()
        .clamp(DVec3::ZERO, DVec3::splat(u32::MAX as f64))
        .as_uvec3()
        .to_array()
}

/// Triangles of cell ids to triangles of cell means (`sums`: position sums and counts),
/// dropping degenerate and repeated ones.
fn assemble(ids: impl Iterator<Item = [u32; 3]>, sums: &[(DVec3, u32)]) -> Option<Vec<[Vec3; 3]>> {
    let reps: Vec<Vec3> = sums
        .iter()
        .map(|(s, n)| (*s / (*n).max(1) as f64).as_vec3())
        .collect();
    let mut seen: std::collections::HashSet<[u32; 3], std::hash::BuildHasherDefault<Mix>> =
        Default::default();
    let mut out = Vec::new();
    for [a, b, c] in ids {
        if a == b || b == c || c == a {
            continue;
        }
        // The same oriented triangle whatever corner it starts at.
        let canon = if a < b && a < c {
            [a, b, c]
        } else if b < c {
            [b, c, a]
        } else {
            [c, a, b]
        };
        if seen.insert(canon) {
            out.push([reps[a as usize], reps[b as usize], reps[c as usize]]);
        }
    }
    (!out.is_empty()).then_some(out)
}

/// [`cluster`] on the object's welded vertices (`bounds`: its box). A welded vertex counts
/// once per corner that uses it in its cell's mean.
fn cluster_welded(welded: &Welded, bounds: &Bounds, cell: f32) -> Option<Vec<[Vec3; 3]>> {
    let side = bounds.extent() as f64 * cell as f64;
    if bounds.is_empty() || side <= 0.0 {
        return None;
    }
    let lo = bounds.min.as_dvec3();
    let mut uses = vec![0u32; welded.positions.len()];
    for t in &welded.corners {
        for &v in t {
            uses[v as usize] += 1;
        }
    }
    let mut cells: MixMap<[u32; 3], u32> = MixMap::default();
    let mut sums: Vec<(DVec3, u32)> = Vec::new();
    let of_vertex: Vec<u32> = welded
        .positions
        .iter()
        .zip(&uses)
        .map(|(&v, &n)| {
            let id = *cells.entry(cell_key(v, lo, side)).or_insert_with(|| {
                sums.push((DVec3::ZERO, 0));
                sums.len() as u32 - 1
            });
            let s = &mut sums[id as usize];
            s.0 += v.as_dvec3() * n as f64;
            s.1 += n;
            id
        })
        .collect();
    assemble(
        welded
            .corners
            .iter()
            .map(|t| t.map(|v| of_vertex[v as usize])),
        &sums,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::proxies::test_meshes::*;

    #[test]
    fn clustering_reduces_and_fine_cells_keep_the_mesh() {
        for scale in [1e-4f32, 1.0, 1e4] {
            // Level 5: edges of ~1.5% of the box, half a 3% cell.
            let ball = bumpy_ball(5, Vec3::new(2.0, 0.0, 1.0) * scale, scale, 0.2);
            let scene = scene_of(std::slice::from_ref(&ball));
            let set = ProxySet::clustered(&scene, None, 0.03).unwrap();
            assert_eq!(set.kind(), ProxyKind::General);
            let n = set.num_triangles();
            assert!(
                n > 1000 && n < ball.len() / 2,
                "scale {scale}: {n} of {}",
                ball.len()
            );
            // Representatives are means of vertices: inside the object's box.
            let (ob, pb) = (Bounds::of_triangles(&ball), set.scene().bounds());
            assert!(pb.min.cmpge(ob.min).all() && pb.max.cmple(ob.max).all());
            // Cells far below the vertex spacing merge nothing.
            let fine = ProxySet::clustered(&scene, None, 1e-6).unwrap();
            assert_eq!(proxy_triangles(&fine, 0), ball, "scale {scale}");
            for target in [1000, 50, 1] {
                let set = ProxySet::clustered_to(&scene, None, target).unwrap();
                assert!(
                    set.num_triangles() <= target.max(12),
                    "{target}: {}",
                    set.num_triangles()
                );
            }
            let all = ProxySet::clustered_to(&scene, None, ball.len()).unwrap();
            assert_eq!(proxy_triangles(&all, 0), ball);
        }
        let scene = scene_of(&[bumpy_ball(1, Vec3::ZERO, 1.0, 0.0)]);
        for bad in [0.0, -0.1, 1.01, f32::NAN, f32::INFINITY] {
            let err = ProxySet::clustered(&scene, None, bad).unwrap_err();
            assert!(err.to_string().starts_with("cell"), "{bad}: {err}");
        }
        let err = ProxySet::clustered_to(&scene, None, 0).unwrap_err();
        assert!(err.to_string().starts_with("target"), "{err}");
    }
}
