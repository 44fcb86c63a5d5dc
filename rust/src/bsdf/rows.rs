//! Materials over batches of rows: [`Material::eval`], [`Material::pdf`] and
//! [`Material::sample`] once per row of slices, into slices the caller owns (what
//! `Material.eval`, `pdf` and `sample` of the Python bindings return). Rows are
//! independent, so batches are spread over rayon's pool and the result is the same for
//! any thread count.

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::bsdf::Material;
use crate::error::{Error, Result};
use crate::parallel::{check_rows, MIN_ROWS_PER_TASK};

/// Checks that `wo`, `wi` and an output of `out` rows have as many rows as `normals`.
fn check_shading(normals: &[Vec3], wo: &[Vec3], wi: &[Vec3], out: usize) -> Result<()> {
    check_rows("wo", wo.len(), normals.len(), "normals")?;
    check_rows("wi", wi.len(), normals.len(), "normals")?;
    check_rows("out", out, normals.len(), "normals")
}

/// `out[k] = m.eval(normals[k], wo[k], wi[k])`: the BRDF in 1/sr per RGB channel, no
/// cosine. `normals`, `wo` and `wi` are unit vectors (not checked; see [`Material::eval`]
/// for others). Every slice has the rows of `normals`, else [`Error::InvalidArgument`]
/// names the first that differs and `out` is untouched.
pub fn eval_rows(
    m: &Material,
    normals: &[Vec3],
    wo: &[Vec3],
    wi: &[Vec3],
    out: &mut [[f32; 3]],
) -> Result<()> {
    check_shading(normals, wo, wi, out.len())?;
    out.par_iter_mut()
        .with_min_len(MIN_ROWS_PER_TASK)
        .enumerate()
        .for_each(|(k, o)| *o = m.eval(normals[k], wo[k], wi[k]).to_array());
    Ok(())
}

/// `out[k] = m.pdf(normals[k], wo[k], wi[k])`: the solid-angle density (1/sr) of
/// [`sample_rows`]. Shapes as for [`eval_rows`].
pub fn pdf_rows(
    m: &Material,
    normals: &[Vec3],
    wo: &[Vec3],
    wi: &[Vec3],
    out: &mut [f64],
) -> Result<()> {
    check_shading(normals, wo, wi, out.len())?;
    out.par_iter_mut()
        .with_min_len(MIN_ROWS_PER_TASK)
        .enumerate()
        .for_each(|(k, o)| *o = m.pdf(normals[k], wo[k], wi[k]));
    Ok(())
}

/// Samples `wi[k]` for `normals[k]` and `wo[k]` (unit vectors) with the uniforms `u[k]`
/// in `[0, 1]`: `u[k][0]` picks the lobe, `u[k][1..]` the direction (each kept below 1, so
/// the sampler sees `[0, 1)`). `valid[k]` says whether [`Material::sample`] gave a
/// direction; rows without one hold zeros. `u` outside `[0, 1]` (or NaN) is an
/// [`Error::InvalidArgument`] naming the first bad row, as are slices whose rows differ
/// from `normals`'; the outputs are then untouched.
pub fn sample_rows(
    m: &Material,
    normals: &[Vec3],
    wo: &[Vec3],
    u: &[[f32; 3]],
    wi: &mut [[f32; 3]],
    valid: &mut [bool],
) -> Result<()> {
    let n = normals.len();
    check_rows("wo", wo.len(), n, "normals")?;
    check_rows("u", u.len(), n, "normals")?;
    check_rows("wi", wi.len(), n, "normals")?;
    check_rows("valid", valid.len(), n, "normals")?;
    if let Some(bad) = u
        .iter()
        .position(|r| r.iter().any(|x| !(0.0..=1.0).contains(x)))
    {
        return Err(Error::invalid(
            format!("u[{bad}]"),
            format!("must lie in [0, 1], got {:?}", u[bad]),
        ));
    }
    let below_one = |x: f32| x.min(1.0 - f32::EPSILON / 2.0);
    wi.par_iter_mut()
        .zip(valid.par_iter_mut())
        .with_min_len(MIN_ROWS_PER_TASK)
        .enumerate()
        .for_each(|(k, (w, ok))| {
            let r = u[k];
            let d = Vec2::new(below_one(r[1]), below_one(r[2]));
            (*w, *ok) = match m.sample(normals[k], wo[k], below_one(r[0]), d) {
                Some(s) => (s.to_array(), true),
                None => ([0.0; 3], false),
            };
        });
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::octahedral::square_to_sphere;

    /// A spread of unit directions: the equal-area map of a jittered grid.
    fn directions(count: usize, salt: u32) -> Vec<Vec3> {
        (0..count)
            .map(|i| {
                let h = (i as u32).wrapping_mul(0x9E37_79B9).wrapping_add(salt);
                let x = (h % 1021) as f32 / 1021.0;
                let y = ((h / 1021) % 1019) as f32 / 1019.0;
                square_to_sphere(glam::Vec2::new(x, y))
            })
            .collect()
    }

    fn uniforms(count: usize) -> Vec<[f32; 3]> {
        (0..count)
            .map(|i| {
                let h = (i as u32).wrapping_mul(2_654_435_761);
                let f = |k: u32| ((h ^ k) % 10_007) as f32 / 10_007.0;
                [f(1), f(7), f(13)]
            })
            .collect()
    }

    fn materials() -> Vec<Material> {
        vec![
            Material::lambert([0.8, 0.5, 0.2]).unwrap(),
            Material::phong([0.3, 0.2, 0.1], [0.5, 0.6, 0.7], 80.0).unwrap(),
        ]
    }

    // More rows than one task holds, so the pool splits the batch.
    const ROWS: usize = 3 * MIN_ROWS_PER_TASK + 17;

    #[test]
    fn rows_equal_per_row_calls_for_any_thread_count() {
        let (n, o, i) = (
            directions(ROWS, 1),
            directions(ROWS, 2),
            directions(ROWS, 3),
        );
        let u = uniforms(ROWS);
        for m in materials() {
            for threads in [1, 3] {
                let (f, p, w, ok) = crate::parallel::with_threads(Some(threads), || {
                    let mut f = vec![[0.0f32; 3]; ROWS];
                    let mut p = vec![0.0f64; ROWS];
                    let mut w = vec![[0.0f32; 3]; ROWS];
                    let mut ok = vec![false; ROWS];
                    eval_rows(&m, &n, &o, &i, &mut f).unwrap();
                    pdf_rows(&m, &n, &o, &i, &mut p).unwrap();
                    sample_rows(&m, &n, &o, &u, &mut w, &mut ok).unwrap();
                    (f, p, w, ok)
                })
                .unwrap();
                for k in 0..ROWS {
                    assert_eq!(f[k], m.eval(n[k], o[k], i[k]).to_array());
                    assert_eq!(p[k].to_bits(), m.pdf(n[k], o[k], i[k]).to_bits());
                    let s = m.sample(n[k], o[k], u[k][0], Vec2::new(u[k][1], u[k][2]));
                    assert_eq!(ok[k], s.is_some());
                    assert_eq!(w[k], s.map_or([0.0; 3], |s| s.to_array()));
                }
                assert!(ok.iter().any(|&v| v) && ok.iter().any(|&v| !v));
            }
        }
    }

    #[test]
    fn a_uniform_of_one_is_kept_below_one() {
        let m = materials()[1];
        let (n, o) = (vec![Vec3::Y], vec![Vec3::new(0.6, 0.8, 0.0)]);
        let mut w = [[0.0f32; 3]];
        let mut ok = [false];
        sample_rows(&m, &n, &o, &[[1.0, 1.0, 1.0]], &mut w, &mut ok).unwrap();
        let below = 1.0 - f32::EPSILON / 2.0;
        let s = m.sample(n[0], o[0], below, Vec2::splat(below));
        assert_eq!(
            (w[0], ok[0]),
            (s.map_or([0.0; 3], |s| s.to_array()), s.is_some())
        );
    }

    #[test]
    fn shapes_and_uniforms_are_checked_before_anything_is_written() {
        let m = materials()[0];
        let n = directions(4, 1);
        let short = directions(3, 2);
        let mut out = vec![[9.0f32; 3]; 4];
        let e = eval_rows(&m, &n, &short, &n, &mut out).unwrap_err();
        assert_eq!(e.to_string(), "wo: expected 4 rows like normals, got 3");
        let e = eval_rows(&m, &n, &n, &short, &mut out).unwrap_err();
        assert_eq!(e.to_string(), "wi: expected 4 rows like normals, got 3");
        let mut pdf = vec![9.0f64; 3];
        assert!(pdf_rows(&m, &n, &n, &n, &mut pdf).is_err());
        assert!(out.iter().all(|r| *r == [9.0; 3]) && pdf.iter().all(|&p| p == 9.0));
        let mut u = uniforms(4);
        u[2][1] = 1.5;
        let (mut w, mut ok) = (vec![[9.0f32; 3]; 4], vec![true; 4]);
        let e = sample_rows(&m, &n, &n, &u, &mut w, &mut ok).unwrap_err();
        assert!(
            e.to_string().starts_with("u[2]: must lie in [0, 1], got"),
            "{e}"
        );
        u[2][1] = f32::NAN;
        assert!(sample_rows(&m, &n, &n, &u, &mut w, &mut ok).is_err());
        let e = sample_rows(&m, &n, &n, &u[..3], &mut w, &mut ok).unwrap_err();
        assert_eq!(e.to_string(), "u: expected 4 rows like normals, got 3");
        assert!(w.iter().all(|r| *r == [9.0; 3]) && ok.iter().all(|&v| v));
        // Empty batches are fine.
        eval_rows(&m, &[], &[], &[], &mut []).unwrap();
        sample_rows(&m, &[], &[], &[], &mut [], &mut []).unwrap();
    }
}
