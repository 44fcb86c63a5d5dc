//! VF §3.3's last step: joint bilateral upsampling of the indirect image to the camera's
//! resolution. A camera pixel takes its four nearest indirect pixels (centres aligned)
//! weighted bilinearly times the joint bilateral weight of their surfaces
//! ([`super::Surfel::weight`]), normalised; where none lies on its surface, the ones that
//! saw a surface by the bilinear weight alone; a miss, or a pixel with no such
//! neighbour, gets zero. At equal resolutions every pixel is its own only neighbour: the
//! identity.

use glam::DVec3;

use super::gather::bilinear;
use super::Surfel;
use crate::error::Result;

/// Upsamples `src` (`sw x sh`, row-major, with its surfels) to `dst`'s `dw x dh` surfels.
/// Deterministic; polls the current stop between rows.
#[allow(clippy::too_many_arguments)]
pub fn upsample(
    src: &[DVec3],
    src_surfels: &[Surfel],
    sw: usize,
    sh: usize,
    dst_surfels: &[Surfel],
    dw: usize,
    dh: usize,
    depth_tol: f32,
    normal_tol: f32,
) -> Result<Vec<[f32; 3]>> {
    let rows: Vec<usize> = (0..dh).collect();
    let per_row = crate::parallel::map_in_order(&rows, |&y| {
        let mut out = Vec::with_capacity(dw);
        for x in 0..dw {
            let me = &dst_surfels[y * dw + x];
            if !me.depth.is_finite() {
                out.push([0.0; 3]);
                continue;
            }
            let near = bilinear(x, y, dw, dh, sw, sh);
            let mut ws = near.map(|(q, wl)| wl * me.weight(&src_surfels[q], depth_tol, normal_tol));
            let mut n: f32 = ws.iter().sum();
            if n.is_nan() || n <= 0.0 {
                ws = near.map(|(q, wl)| {
                    if src_surfels[q].depth.is_finite() {
                        wl
                    } else {
                        0.0
                    }
                });
                n = ws.iter().sum();
            }
            if n.is_nan() || n <= 0.0 {
                out.push([0.0; 3]);
                continue;
            }
            let mut v = DVec3::ZERO;
            for ((q, _), wq) in near.iter().zip(ws) {
                if wq > 0.0 {
                    v += src[*q] * (wq / n) as f64;
                }
            }
            out.push(v.as_vec3().to_array());
        }
        out
    })?;
    Ok(per_row.into_iter().flatten().collect())
}
