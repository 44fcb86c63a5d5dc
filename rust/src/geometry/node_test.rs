//! Conservative ray/box test for obvhs's compressed 8-wide nodes.
//!
//! obvhs's own test (`CwBvhNode::intersect_ray`) clamps every entry distance to `1e-4` and
//! compares rounded slab distances as they are, so a ray that starts on a surface, or passes
//! exactly through a vertex on a box face, can be culled although its triangle is hit. Here
//! each slab interval is widened by a bound on its rounding error (after Ize, "Robust BVH
//! Ray Traversal", JCGT 2013, adapted to the quantised form `t = q a + b`), entry distances
//! are clamped at 0, and near/far planes are chosen from the sign of the inverse direction,
//! so that `-0.0` components cannot swap them. The test only ever admits more boxes; the
//! watertight triangle test decides every hit.

use glam::{Vec3A, Vec4};
use obvhs::cwbvh::node::{extract_byte64, CwBvhNode};
use obvhs::ray::Ray;

/// Relative rounding bound for `t = q a + b` with `a`, `b` themselves rounded products
/// (a few ulps), with a factor 2 of margin.
const SLAB_ERROR: f32 = 8.0 * f32::EPSILON * 0.5;

#[inline(always)]
fn quantised(v: &[u8; 8], i: usize) -> Vec4 {
    Vec4::new(
        v[i * 4] as f32,
        v[i * 4 + 1] as f32,
        v[i * 4 + 2] as f32,
        v[i * 4 + 3] as f32,
    )
}

/// The hit mask of `node`'s children for `ray` in obvhs's layout (inner children in the
/// high byte, leaf primitives in the low 24 bits), for use as the node expression of
/// `obvhs::traverse!`. `ray.tmin` is ignored (0 is used).
#[inline(always)]
pub fn intersect_node(node: &CwBvhNode, ray: &Ray, oct_inv4: u32) -> u32 {
    let a = node.compute_extent() * ray.inv_direction;
    let b = (Vec3A::from(node.p) - ray.origin) * ray.inv_direction;
    let err = (b.abs() + a.abs() * 255.0) * SLAB_ERROR;
    let far_limit = Vec4::splat(ray.tmax + ray.tmax * SLAB_ERROR);
    let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
    let slab = |lo: &[u8; 8], hi: &[u8; 8], i: usize, a: f32, b: f32, e: f32| {
        let (q_lo, q_hi) = (quantised(lo, i), quantised(hi, i));
        let (near, far) = if a < 0.0 { (q_hi, q_lo) } else { (q_lo, q_hi) };
        let (a, b) = (Vec4::splat(a), Vec4::splat(b));
        (near * a + b - Vec4::splat(e), far * a + b + Vec4::splat(e))
    };
    let mut hit_mask = 0u32;
    for i in 0..2 {
        let (nx, fx) = slab(&node.child_min_x, &node.child_max_x, i, a.x, b.x, err.x);
        let (ny, fy) = slab(&node.child_min_y, &node.child_max_y, i, a.y, b.y, err.y);
        let (nz, fz) = slab(&node.child_min_z, &node.child_max_z, i, a.z, b.z, err.z);
        let tmin = nx.max(ny).max(nz).max(Vec4::ZERO);
        let tmax = fx.min(fy).min(fz).min(far_limit);
        let mut mask = tmin.cmple(tmax).bitmask();
        while mask != 0 {
            let j = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let child = i * 4 + j;
            hit_mask |= extract_byte64(child_bits8, child) << extract_byte64(bit_index8, child);
        }
    }
    hit_mask
}
