//! An environment map over batches of rows: [`EnvMap::eval`], [`EnvMap::pdf`],
//! [`EnvMap::sample`] and [`EnvMap::invert`] once per row of slices, into slices the caller
//! owns (what `EnvMap.eval`, `pdf`, `sample` and `invert` of the Python bindings return).
//! Rows are independent, so batches are spread over rayon's pool and the result is the
//! same for any thread count.

use glam::{DVec2, Vec3};
use rayon::prelude::*;

use super::EnvMap;
use crate::error::{Error, Result};
use crate::parallel::{check_rows, MIN_ROWS_PER_TASK};

/// `out[k] = env.eval(dirs[k])`: radiance (RGB) arriving from each direction (pointing
/// away from the receiver; see [`EnvMap::eval`] for zero or non-finite ones). `out` must
/// have the rows of `dirs`, else [`Error::InvalidArgument`] and `out` is untouched.
pub fn eval_rows(env: &EnvMap, dirs: &[Vec3], out: &mut [[f32; 3]]) -> Result<()> {
    check_rows("out", out.len(), dirs.len(), "the input")?;
    out.par_iter_mut()
        .with_min_len(MIN_ROWS_PER_TASK)
        .enumerate()
        .for_each(|(k, o)| *o = env.eval(dirs[k]).to_array());
    Ok(())
}

/// `out[k] = env.pdf(dirs[k])`: the solid-angle density (1/sr) of [`sample_rows`]; zeros
/// for a black map. Shapes as for [`eval_rows`].
pub fn pdf_rows(env: &EnvMap, dirs: &[Vec3], out: &mut [f64]) -> Result<()> {
    check_rows("out", out.len(), dirs.len(), "the input")?;
    out.par_iter_mut()
        .with_min_len(MIN_ROWS_PER_TASK)
        .enumerate()
        .for_each(|(k, o)| *o = env.pdf(dirs[k]));
    Ok(())
}

/// Draws `dirs[k]` (unit) with solid-angle density `pdf[k]` (1/sr) from `u[k] ∈ [0, 1)²`.
/// A black map cannot be sampled: its rows get `+y` and density 0 (callers that must
/// refuse it check [`EnvMap::is_black`]). `u` outside `[0, 1)` (or NaN) is an
/// [`Error::InvalidArgument`] naming the first bad row, as are outputs whose rows differ
/// from `u`'s; the outputs are then untouched.
pub fn sample_rows(
    env: &EnvMap,
    u: &[[f64; 2]],
    dirs: &mut [[f32; 3]],
    pdf: &mut [f64],
) -> Result<()> {
    check_rows("dirs", dirs.len(), u.len(), "the input")?;
    check_rows("pdf", pdf.len(), u.len(), "the input")?;
    if let Some(i) = u
        .iter()
        .position(|r| !r.iter().all(|c| (0.0..1.0).contains(c)))
    {
        return Err(Error::invalid(
            "u",
            format!("row {i} is {:?}; values must lie in [0, 1)", u[i]),
        ));
    }
    dirs.par_iter_mut()
        .zip(pdf.par_iter_mut())
        .with_min_len(MIN_ROWS_PER_TASK)
        .enumerate()
        .for_each(|(k, (d, p))| {
            let (dir, density) = env
                .sample(DVec2::new(u[k][0], u[k][1]))
                .unwrap_or((Vec3::Y, 0.0));
            (*d, *p) = (dir.to_array(), density);
        });
    Ok(())
}

/// `out[k]`: the `u ∈ [0, 1)²` that [`EnvMap::sample`] maps to `dirs[k]`, NaN for a
/// direction of zero density (every direction of a black map). Shapes as for
/// [`eval_rows`].
pub fn invert_rows(env: &EnvMap, dirs: &[Vec3], out: &mut [[f64; 2]]) -> Result<()> {
    check_rows("out", out.len(), dirs.len(), "the input")?;
    out.par_iter_mut()
        .with_min_len(MIN_ROWS_PER_TASK)
        .enumerate()
        .for_each(|(k, o)| *o = env.invert(dirs[k]).unwrap_or(DVec2::NAN).to_array());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::octahedral::square_to_sphere;

    // More rows than one task holds, so the pool splits the batch.
    const ROWS: usize = 3 * MIN_ROWS_PER_TASK + 17;

    /// A map whose texels differ (one black quarter, so some pdfs are zero).
    fn map() -> EnvMap {
        let res = 32u32;
        let texels = (0..res * res)
            .map(|t| {
                let (x, y) = (t % res, t / res);
                if x < res / 2 && y < res / 2 {
                    [0.0; 3]
                } else {
                    [1.0 + x as f32, 0.5 + y as f32, 0.25 * (x ^ y) as f32]
                }
            })
            .collect();
        EnvMap::from_octahedral(res, texels).unwrap()
    }

    fn uniforms(count: usize) -> Vec<[f64; 2]> {
        (0..count)
            .map(|i| {
                let h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
                [
                    (h >> 11) as f64 / (1u64 << 53) as f64,
                    (h % 1_000_003) as f64 / 1_000_003.0,
                ]
            })
            .collect()
    }

    fn directions(count: usize) -> Vec<Vec3> {
        uniforms(count)
            .iter()
            .map(|u| square_to_sphere(DVec2::from(*u).as_vec2()))
            .collect()
    }

    #[test]
    fn rows_equal_per_row_calls_for_any_thread_count() {
        let env = map();
        let (d, u) = (directions(ROWS), uniforms(ROWS));
        for threads in [1, 3] {
            let (f, p, sd, sp, inv) = crate::parallel::with_threads(Some(threads), || {
                let mut f = vec![[0.0f32; 3]; ROWS];
                let mut p = vec![0.0f64; ROWS];
                let mut sd = vec![[0.0f32; 3]; ROWS];
                let mut sp = vec![0.0f64; ROWS];
                let mut inv = vec![[0.0f64; 2]; ROWS];
                eval_rows(&env, &d, &mut f).unwrap();
                pdf_rows(&env, &d, &mut p).unwrap();
                sample_rows(&env, &u, &mut sd, &mut sp).unwrap();
                invert_rows(&env, &d, &mut inv).unwrap();
                (f, p, sd, sp, inv)
            })
            .unwrap();
            for k in 0..ROWS {
                assert_eq!(f[k], env.eval(d[k]).to_array());
                assert_eq!(p[k].to_bits(), env.pdf(d[k]).to_bits());
                let (dir, density) = env.sample(DVec2::from(u[k])).unwrap();
                assert_eq!(
                    (sd[k], sp[k].to_bits()),
                    (dir.to_array(), density.to_bits())
                );
                match env.invert(d[k]) {
                    Some(v) => assert_eq!(inv[k], v.to_array()),
                    None => assert!(inv[k].iter().all(|x| x.is_nan())),
                }
            }
            assert!(p.contains(&0.0) && p.iter().any(|&x| x > 0.0));
        }
    }

    #[test]
    fn a_black_map_gives_up_and_zero_and_nan_rows() {
        let env = EnvMap::constant([0.0; 3], 8).unwrap();
        assert!(env.is_black());
        let (mut d, mut p) = (vec![[0.0f32; 3]; 2], vec![1.0f64; 2]);
        sample_rows(&env, &[[0.25, 0.5], [0.0, 0.999]], &mut d, &mut p).unwrap();
        assert_eq!((d, p), (vec![[0.0, 1.0, 0.0]; 2], vec![0.0; 2]));
        let mut inv = vec![[0.0f64; 2]; 1];
        invert_rows(&env, &[Vec3::X], &mut inv).unwrap();
        assert!(inv[0].iter().all(|x| x.is_nan()));
    }

    #[test]
    fn shapes_and_uniforms_are_checked_before_anything_is_written() {
        let env = map();
        let mut out = vec![[9.0f32; 3]; 2];
        assert!(eval_rows(&env, &directions(3), &mut out).is_err());
        assert!(out.iter().all(|r| *r == [9.0; 3]));
        let (mut d, mut p) = (vec![[9.0f32; 3]; 3], vec![9.0f64; 3]);
        for bad in [1.0, -0.1, f64::NAN] {
            let mut u = uniforms(3);
            u[1][0] = bad;
            let e = sample_rows(&env, &u, &mut d, &mut p).unwrap_err();
            assert!(e.to_string().starts_with("u: row 1 is ["), "{e}");
        }
        assert!(sample_rows(&env, &uniforms(2), &mut d, &mut p).is_err());
        assert!(d.iter().all(|r| *r == [9.0; 3]) && p.iter().all(|&x| x == 9.0));
        eval_rows(&env, &[], &mut []).unwrap();
    }
}
