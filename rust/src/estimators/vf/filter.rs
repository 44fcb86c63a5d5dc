//! VF eq. 4: the visibility filter. A low-resolution pixel's list of visible voxels
//! becomes the union of the lists of the pixels of a `(2m+1) x (2n+1)` window around it
//! that lie on its surface (δ_d · δ_n = 1: [`super::Surfel::same_surface`]). A pixel
//! always passes its own tests, so the output holds the input; a 1 x 1 window is the
//! identity; a pixel that saw no surface keeps its empty list.

use super::march::Lists;
use super::Surfel;
use crate::error::Result;

/// Eq. 4 over a `width x height` image of `lists` and `surfels` (row-major) with a
/// `side x side` window (`side` odd, clipped at the borders). Deterministic; polls the
/// current stop between rows.
pub fn filter(
    lists: &Lists,
    surfels: &[Surfel],
    width: usize,
    height: usize,
    side: u32,
    depth_tol: f32,
    normal_tol: f32,
) -> Result<Lists> {
    debug_assert_eq!(lists.len(), width * height);
    if side <= 1 {
        return Ok(lists.clone());
    }
    let m = (side / 2) as isize;
    let rows: Vec<usize> = (0..height).collect();
    let per_row = crate::parallel::map_in_order(&rows, |&y| {
        let mut out = Vec::with_capacity(width);
        for x in 0..width {
            let p = y * width + x;
            let me = &surfels[p];
            if !me.depth.is_finite() {
                out.push(Vec::new());
                continue;
            }
            let mut keys: Vec<u64> = Vec::new();
            for dy in -m..=m {
                let qy = y as isize + dy;
                if qy < 0 || qy >= height as isize {
                    continue;
                }
                for dx in -m..=m {
                    let qx = x as isize + dx;
                    if qx < 0 || qx >= width as isize {
                        continue;
                    }
                    let q = qy as usize * width + qx as usize;
                    if me.same_surface(&surfels[q], depth_tol, normal_tol) {
                        keys.extend_from_slice(lists.get(q));
                    }
                }
            }
            keys.sort_unstable();
            keys.dedup();
            out.push(keys);
        }
        out
    })?;
    Ok(Lists::from_rows(per_row.into_iter().flatten()))
}
