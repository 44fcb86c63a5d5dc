//! The lighting side of a transfer preview: an environment map (possibly rotated) as the
//! vector of its integrals over equal-area octahedral cells, `l_c(cell) = ∫_cell L_c dω`.
//! A preview's `J_c = Σ_cell T(cell) l_c(cell)` is then one dot product per pixel, in that
//! basis or (both sides transformed alike) in Haar wavelets over it.

use glam::{DMat3, DVec3, UVec2};

use crate::error::{Error, Result};
use crate::lights::envmap::{EnvMap, LUMINANCE};
use crate::sampling::octahedral::{morton_encode, texel_center, texel_of, texel_solid_angle};

/// `R` as a checked rotation: finite, orthonormal to `1e-4` and of determinant `+1`; the
/// error names `rotation`.
pub fn check_rotation(r: &DMat3) -> Result<()> {
    let cols = [r.x_axis, r.y_axis, r.z_axis];
    if !cols.iter().all(|c| c.is_finite()) {
        return Err(Error::invalid("rotation", "must be finite"));
    }
    let rtr = r.transpose() * *r;
    let off = (rtr - DMat3::IDENTITY).to_cols_array();
    if off.iter().any(|x| x.abs() > 1e-4) || (r.determinant() - 1.0).abs() > 1e-4 {
        return Err(Error::invalid(
            "rotation",
            "must be a rotation matrix (orthonormal, determinant +1)",
        ));
    }
    Ok(())
}

/// A rotation by `degrees` about +y, right-handed, as [`EnvMap::rotated`] turns a map: a
/// feature at `ω` moves to `R ω` (+90° takes +x to -z). Non-finite angles are refused
/// with an error naming `rotation`.
pub fn rotation_about_y(degrees: f64) -> Result<DMat3> {
    if !degrees.is_finite() {
        return Err(Error::invalid("rotation", "must be finite"));
    }
    Ok(DMat3::from_rotation_y(degrees.to_radians()))
}

/// `∫_cell L_c dω` over the `4^level` cells of `level` (Morton order) of `env` turned by
/// `rotation` (a feature at `ω` moves to `R ω`; `None` leaves it). Unrotated, the sums are
/// exact (texels nest in cells; a map coarser than the cells is split evenly). Rotated,
/// each texel of the map — split first to at least 4 x 4 per cell — goes whole to the cell
/// its rotated centre falls in: one pass over the texels.
pub fn cell_integrals(env: &EnvMap, level: u32, rotation: Option<&DMat3>) -> Result<Vec<[f64; 3]>> {
    Ok(project(env, level, rotation, false)?.0)
}

/// [`cell_integrals`] and, per cell, the luminance-weighted sum of the (turned) texel
/// directions in it: normalised, the direction a cell's light comes from on average (a
/// sun's direction within its cell).
pub fn cell_integrals_and_centroids(
    env: &EnvMap,
    level: u32,
    rotation: Option<&DMat3>,
) -> Result<(Vec<[f64; 3]>, Vec<DVec3>)> {
    project(env, level, rotation, true)
}

fn project(
    env: &EnvMap,
    level: u32,
    rotation: Option<&DMat3>,
    centroids: bool,
) -> Result<(Vec<[f64; 3]>, Vec<DVec3>)> {
    if let Some(r) = rotation {
        check_rotation(r)?;
    }
    let cells = 1usize << level;
    let min_res = if rotation.is_some() { cells * 4 } else { cells };
    let env = env.at_least(min_res as u32)?;
    let res = env.resolution();
    let omega = texel_solid_angle(res);
    let mut out = vec![[0.0f64; 3]; cells * cells];
    let mut dirs = vec![DVec3::ZERO; if centroids { cells * cells } else { 0 }];
    let depth = res.trailing_zeros();
    for (i, t) in env.texels().iter().enumerate() {
        let (x, y) = (i as u32 % res, i as u32 / res);
        let centre = || texel_center(UVec2::new(x, y), res).as_dvec3();
        let (cell, d) = match rotation {
            None if !centroids => (morton_encode(x, y) >> (2 * (depth - level)), DVec3::ZERO),
            None => (morton_encode(x, y) >> (2 * (depth - level)), centre()),
            Some(r) => {
                let d = *r * centre();
                let c = texel_of(d.as_vec3(), cells as u32);
                (morton_encode(c.x, c.y), d)
            }
        };
        let o = &mut out[cell as usize];
        for k in 0..3 {
            o[k] += t[k] as f64 * omega;
        }
        if centroids {
            let lum: f64 = t.iter().zip(LUMINANCE).map(|(&c, w)| c as f64 * w).sum();
            dirs[cell as usize] += d * lum;
        }
    }
    Ok((out, dirs))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::octahedral::texel_of;
    use glam::Vec3;

    fn sun_map(dir: Vec3) -> EnvMap {
        let res = 64;
        let mut texels = vec![[0.1f32, 0.2, 0.3]; (res * res) as usize];
        let t = texel_of(dir.normalize(), res);
        texels[(t.y * res + t.x) as usize] = [500.0, 400.0, 300.0];
        EnvMap::from_octahedral(res, texels).unwrap()
    }

    /// Unrotated sums are the map's power, cell by cell: a constant map gives every cell
    /// `c · 4π / 4^level`, and the total is `total_power`.
    #[test]
    fn unrotated_sums_are_exact() {
        let env = EnvMap::constant([0.5, 1.0, 2.0], 32).unwrap();
        for level in [2u32, 5, 7] {
            let sums = cell_integrals(&env, level, None).unwrap();
            let cell = 4.0 * std::f64::consts::PI / (1u64 << (2 * level)) as f64;
            for s in &sums {
                for (k, c) in [0.5, 1.0, 2.0].iter().enumerate() {
                    assert!((s[k] - c * cell).abs() < 1e-12 * c, "level {level}");
                }
            }
        }
        // One bright texel: its cell holds the background's share plus exactly its power.
        let sun = Vec3::new(0.3, 0.8, -0.2);
        let env = sun_map(sun);
        let sums = cell_integrals(&env, 4, None).unwrap();
        let t = texel_of(sun.normalize(), 16);
        let cell = sums[morton_encode(t.x, t.y) as usize];
        let omega = texel_solid_angle(64);
        let expected = 15.0 * 0.1 * omega + 500.0 * omega;
        assert!((cell[0] - expected).abs() < 1e-9 * expected, "{cell:?}");
        let power = env.total_power();
        for k in 0..3 {
            let s: f64 = sums.iter().map(|s| s[k]).sum();
            assert!((s - power[k]).abs() < 1e-9 * power[k]);
        }
    }

    /// A rotation moves a bright texel's power to the cell of its rotated direction and
    /// keeps the total; a full turn is the identity.
    #[test]
    fn rotation_moves_power() {
        let sun = Vec3::new(0.6, 0.5, 0.2).normalize();
        let env = sun_map(sun);
        let r = rotation_about_y(70.0).unwrap();
        let sums = cell_integrals(&env, 4, Some(&r)).unwrap();
        let moved = texel_of((r * sun.as_dvec3()).as_vec3(), 16);
        let cell = morton_encode(moved.x, moved.y) as usize;
        let sun_power = 500.0 * texel_solid_angle(64);
        assert!(sums[cell][0] > 0.9 * sun_power, "{:?}", sums[cell]);
        let total: f64 = sums.iter().map(|s| s[1]).sum();
        assert!((total - env.total_power()[1]).abs() < 1e-9 * total);
        let full = rotation_about_y(360.0).unwrap();
        assert_eq!(
            cell_integrals(&env, 4, Some(&full)).unwrap(),
            cell_integrals(&env, 4, Some(&DMat3::IDENTITY)).unwrap()
        );
        let unrotated = cell_integrals(&env, 4, None).unwrap();
        let turned = cell_integrals(&env, 4, Some(&full)).unwrap();
        for (a, b) in unrotated.iter().zip(&turned) {
            for k in 0..3 {
                assert!((a[k] - b[k]).abs() <= 1e-9 * a[k].abs().max(1e-12));
            }
        }
    }

    /// Any 3D rotation of a smooth map, against a direct quadrature of the turned map
    /// `L(Rᵀ ω)` (8 x 8 equal-area points a cell): what a preview reads of the projection,
    /// `Σ_cell f(cell) l(cell)` for cosine lobes `f` around several normals, agrees within
    /// 0.5%, and the total power exactly. Single cells are off by up to a few percent: a
    /// texel goes whole to the cell of its centre, so a cell gets a texel more or less of
    /// its border; the lobes' sums over many cells average that out.
    #[test]
    fn rotated_projection_matches_quadrature() {
        let res = 128;
        let (a, b) = (Vec3::new(0.3, 0.8, -0.2), Vec3::new(-0.5, 0.1, 0.6));
        let texels = (0..res * res)
            .map(|i| {
                let w = texel_center(UVec2::new(i % res, i / res), res);
                let v = 1.0 + 0.5 * w.dot(a) + 0.25 * w.dot(b).powi(2);
                [v, 0.5 * v, 2.0 - 0.5 * w.dot(a)]
            })
            .collect();
        let env = EnvMap::from_octahedral(res, texels).unwrap();
        let r = DMat3::from_axis_angle(DVec3::new(1.0, 2.0, -0.5).normalize(), 1.1);
        let level = 5;
        let sums = cell_integrals(&env, level, Some(&r)).unwrap();
        let cells = 1u32 << level;
        let sub = 8u32;
        let fine = cells * sub;
        let sub_omega = texel_solid_angle(fine);
        // Quadrature per cell, and the cell centres for the lobes.
        let mut quad = vec![[0.0f64; 3]; sums.len()];
        for y in 0..fine {
            for x in 0..fine {
                let w = texel_center(UVec2::new(x, y), fine);
                let l = env.eval((r.transpose() * w.as_dvec3()).as_vec3());
                let cell = morton_encode(x / sub, y / sub) as usize;
                for k in 0..3 {
                    quad[cell][k] += l[k] as f64 * sub_omega;
                }
            }
        }
        for k in 0..3 {
            let (s, q): (f64, f64) = (
                sums.iter().map(|c| c[k]).sum(),
                quad.iter().map(|c| c[k]).sum(),
            );
            assert!((s - q).abs() < 2e-3 * q, "power {k}: {s} vs {q}");
        }
        for n in [
            Vec3::Y,
            Vec3::X,
            Vec3::new(0.2, -0.9, 0.3).normalize(),
            -Vec3::Z,
        ] {
            let (mut s, mut q) = ([0.0f64; 3], [0.0f64; 3]);
            for y in 0..cells {
                for x in 0..cells {
                    let c = morton_encode(x, y) as usize;
                    let f = texel_center(UVec2::new(x, y), cells).dot(n).max(0.0) as f64;
                    for k in 0..3 {
                        s[k] += f * sums[c][k];
                        q[k] += f * quad[c][k];
                    }
                }
            }
            for k in 0..3 {
                assert!(
                    (s[k] - q[k]).abs() < 5e-3 * q[k],
                    "lobe {n}: {s:?} vs {q:?}"
                );
            }
        }
    }

    #[test]
    fn bad_rotations_are_refused() {
        let env = EnvMap::constant([1.0; 3], 8).unwrap();
        for r in [
            DMat3::from_diagonal(glam::DVec3::new(1.0, 1.0, 2.0)),
            DMat3::from_diagonal(glam::DVec3::new(1.0, 1.0, -1.0)),
            DMat3::from_cols_array(&[f64::NAN; 9]),
        ] {
            let e = cell_integrals(&env, 3, Some(&r)).unwrap_err();
            assert!(e.to_string().contains("rotation"), "{e}");
        }
        assert!(rotation_about_y(f64::NAN).is_err());
    }
}
