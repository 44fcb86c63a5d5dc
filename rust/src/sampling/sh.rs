//! Real spherical harmonics (SH) for the lighting preview's cached transfer: the basis at a
//! direction, its averages over the cells of an octahedral level (to project a per-pixel
//! transfer function), the projection of an octahedral environment map, and the exact
//! rotation of SH coefficients (Ivanic & Ruedenberg, "Rotation matrices for real spherical
//! harmonics. Direct determination by recursion", J. Phys. Chem. 100(15), 1996, with the
//! corrections of their 1998 erratum; also Sloan, "Stupid Spherical Harmonics (SH) Tricks",
//! GDC 2008, §"Rotation").
//!
//! # Conventions
//!
//! - An *order* `n` means the bands `l = 0..n`, `n²` coefficients; coefficient `k` of band `l`
//!   and degree `m ∈ [-l, l]` is `k = l² + l + m` ([`index`]).
//! - The basis is the usual real, orthonormal one (`∫ Y_k Y_j dω = δ_kj` over the unit
//!   sphere), *with* the Condon–Shortley phase, exactly as in Sloan's "Stupid SH Tricks"
//!   (appendix) and pbrt-v2's `SHEvaluate`:
//!   `Y_l^0 = K_l^0 P_l^0(cos θ)`, `Y_l^m = √2 K_l^m P_l^m(cos θ) cos(mφ)` for `m > 0` and
//!   `Y_l^m = √2 K_l^|m| P_l^|m|(cos θ) sin(|m|φ)` for `m < 0`, where `P_l^m` includes the
//!   `(-1)^m` phase and `K_l^m = √((2l+1)/(4π) · (l-m)!/(l+m)!)`.
//! - The SH frame is the library's frame turned so that the polar axis is the library's up:
//!   `θ` is measured from `+y` and `φ` from `+z` towards `+x`, i.e. the SH frame's
//!   `(x', y', z')` is the library's `(z, x, y)` (a cyclic permutation, so still
//!   right-handed). Hence, for a unit direction `d = (x, y, z)` of the library:
//!   `Y_0 = 1/(2√π)`; `Y_1^{-1} = -√(3/4π) x`, `Y_1^0 = √(3/4π) y`, `Y_1^1 = -√(3/4π) z`;
//!   `Y_2^{-2} = ½√(15/π) z x`, `Y_2^{-1} = -½√(15/π) x y`, `Y_2^0 = ¼√(5/π) (3y² - 1)`,
//!   `Y_2^1 = -½√(15/π) y z`, `Y_2^2 = ¼√(15/π) (z² - x²)`
//!   (Sloan's table with his `(x, y, z)` read as our `(z, x, y)`).
//!   A rotation about `+y` (the map's "turn the sky" slider) therefore only mixes `m` with
//!   `-m` inside each band.
//! - Projections are integrals over solid angle (steradians): the coefficient of a radiance
//!   map `L` is `∫ L(ω) Y_k(ω) dω`, in the radiance's unit times sr.
//!
//! The Legendre functions come from the normalised three-term recurrences (as in Press et
//! al., "Numerical Recipes", 3rd ed., §6.7, without the `sin^m θ` factor): no factorial is
//! ever formed, and `sin^m θ · (cos mφ, sin mφ)` is the real and imaginary part of
//! `(x' + i y')^m`, so the evaluation is polynomial in the direction's components (no
//! trigonometry, exact at the poles).

use std::sync::OnceLock;

use glam::{DMat3, DVec3, UVec2};
use rayon::prelude::*;

use super::octahedral;
use crate::error::{Error, Result};

/// Largest supported order (bands `l = 0..16`, 256 coefficients).
pub const MAX_ORDER: u32 = 16;

/// Largest level of a [`CellBasis`]: its `2^(L+2)` sub-texel grid must stay within the
/// octahedral map's Morton range (`2^16` per axis). Memory is the real limit long before:
/// `4^L · order² · 4` bytes.
pub const MAX_CELL_LEVEL: u32 = 13;

/// Number of coefficients of an order: `order²`.
pub const fn coefficient_count(order: u32) -> usize {
    (order as usize) * (order as usize)
}

/// Index of the coefficient of band `l` and degree `m` (`-l <= m <= l`): `l² + l + m`.
pub const fn index(l: u32, m: i32) -> usize {
    ((l as i64) * (l as i64) + l as i64 + m as i64) as usize
}

/// Precomputed recurrence constants for every `(l, m)` with `0 <= m <= l < MAX_ORDER`,
/// indexed by `l (l + 1) / 2 + m`.
struct Tables {
    /// `Q_m^m = K_m^m P_m^m / sin^m θ`, a constant (with the Condon–Shortley sign).
    qmm: [f64; MAX_ORDER as usize],
    /// `√(2m + 3)`: `Q_{m+1}^m = √(2m+3) cos θ Q_m^m`.
    next: [f64; MAX_ORDER as usize],
    /// `a_l^m = √((4l² - 1) / (l² - m²))` for `l >= m + 2`.
    a: Vec<f64>,
    /// `b_l^m = √(((l-1)² - m²) / (4(l-1)² - 1))` for `l >= m + 2`.
    b: Vec<f64>,
}

#[inline]
const fn tri(l: usize, m: usize) -> usize {
    l * (l + 1) / 2 + m
}

fn tables() -> &'static Tables {
    static T: OnceLock<Tables> = OnceLock::new();
    T.get_or_init(|| {
        let n = MAX_ORDER as usize;
        let mut qmm = [0.0; MAX_ORDER as usize];
        let mut next = [0.0; MAX_ORDER as usize];
        qmm[0] = 0.5 / std::f64::consts::PI.sqrt();
        for m in 1..n {
            let mf = m as f64;
            qmm[m] = -((2.0 * mf + 1.0) / (2.0 * mf)).sqrt() * qmm[m - 1];
        }
        for (m, v) in next.iter_mut().enumerate() {
            *v = (2.0 * m as f64 + 3.0).sqrt();
        }
        let mut a = vec![0.0; tri(n, 0)];
        let mut b = vec![0.0; tri(n, 0)];
        for l in 2..n {
            for m in 0..=l - 2 {
                let (lf, mf) = (l as f64, m as f64);
                a[tri(l, m)] = ((4.0 * lf * lf - 1.0) / (lf * lf - mf * mf)).sqrt();
                let l1 = lf - 1.0;
                b[tri(l, m)] = ((l1 * l1 - mf * mf) / (4.0 * l1 * l1 - 1.0)).sqrt();
            }
        }
        Tables { qmm, next, a, b }
    })
}

/// Evaluates the basis at `w` directions at once, structure of arrays: the library's
/// components `x`, `y`, `z` (unit vectors) in, `out[k * w + j]` = `Y_k(d_j)`. `scratch` holds
/// at least `5 w` values. Every inner loop runs over the directions, so it vectorizes.
fn eval_batch(order: u32, x: &[f64], y: &[f64], z: &[f64], out: &mut [f64], scratch: &mut [f64]) {
    let n = order as usize;
    let w = y.len();
    debug_assert!(x.len() == w && z.len() == w && out.len() >= n * n * w);
    if n == 0 || w == 0 {
        return;
    }
    let t = tables();
    let (c, rest) = scratch.split_at_mut(w);
    let (s, rest) = rest.split_at_mut(w);
    let (q0, rest) = rest.split_at_mut(w);
    let (q1, rest) = rest.split_at_mut(w);
    let q2 = &mut rest[..w];
    let sqrt2 = std::f64::consts::SQRT_2;
    for m in 0..n {
        // (c + i s) = √2 (x' + i y')^m = √2 sin^m θ (cos mφ + i sin mφ); x' = z, y' = x.
        if m == 0 {
            c.fill(1.0);
            s.fill(0.0);
        } else if m == 1 {
            for j in 0..w {
                c[j] = sqrt2 * z[j];
                s[j] = sqrt2 * x[j];
            }
        } else {
            for j in 0..w {
                let (cp, sp) = (c[j], s[j]);
                c[j] = z[j] * cp - x[j] * sp;
                s[j] = z[j] * sp + x[j] * cp;
            }
        }
        let write = |l: usize, q: &[f64], out: &mut [f64]| {
            if m == 0 {
                out[index(l as u32, 0) * w..][..w].copy_from_slice(q);
            } else {
                let kp = index(l as u32, m as i32) * w;
                for (j, o) in out[kp..kp + w].iter_mut().enumerate() {
                    *o = q[j] * c[j];
                }
                let kn = index(l as u32, -(m as i32)) * w;
                for (j, o) in out[kn..kn + w].iter_mut().enumerate() {
                    *o = q[j] * s[j];
                }
            }
        };
        // Q_l^m for l = m, m + 1, ... (q0 = Q_{l-2}, q1 = Q_{l-1}, q2 = Q_l).
        q1.fill(t.qmm[m]);
        write(m, q1, out);
        if m + 1 >= n {
            continue;
        }
        let f = t.next[m];
        for j in 0..w {
            q0[j] = q1[j];
            q1[j] = f * y[j] * q0[j];
        }
        write(m + 1, q1, out);
        for l in m + 2..n {
            let (a, b) = (t.a[tri(l, m)], t.b[tri(l, m)]);
            for j in 0..w {
                q2[j] = a * (y[j] * q1[j] - b * q0[j]);
            }
            write(l, q2, out);
            q0.copy_from_slice(q1);
            q1.copy_from_slice(q2);
        }
    }
}

/// All `order²` basis values at the unit direction `dir` (library frame, `|dir| = 1`; not
/// normalised here): `out[k] = Y_k(dir)`, in sr^-½ (`∫ Y_k² dω = 1` over steradians).
///
/// # Panics
/// If `order > MAX_ORDER` or `out.len() != order²`.
pub fn eval(order: u32, dir: DVec3, out: &mut [f64]) {
    assert!(order <= MAX_ORDER, "order {order} > MAX_ORDER");
    assert_eq!(
        out.len(),
        coefficient_count(order),
        "out must hold order² values"
    );
    let mut scratch = [0.0; 5];
    eval_batch(order, &[dir.x], &[dir.y], &[dir.z], out, &mut scratch);
}

/// The centre of texel `(x, y)` of a `res x res` octahedral grid, in `f64`: the same map as
/// [`octahedral::texel_center`] (Clarberg's equal-area map, `+y` at the square's centre)
/// evaluated in double precision, so it is unit length to `~1e-16`.
pub fn texel_center_f64(texel: UVec2, res: u32) -> DVec3 {
    let inv = 1.0 / res as f64;
    octahedral::square_to_sphere_f64(glam::DVec2::new(
        (texel.x as f64 + 0.5) * inv,
        (texel.y as f64 + 0.5) * inv,
    ))
}

/// The SH basis averaged over the cells of an octahedral level, weighted by the cells' solid
/// angle, for projecting functions that are piecewise constant over the cells (a pixel's
/// transfer `B̃ Ṽ` at a coarse level of the map, CAM08 §6.2).
///
/// Invariants: the cells of level `L` are the texels of the `2^L x 2^L` octahedral grid,
/// indexed in Morton order ([`octahedral::morton_encode`]); `values` has `4^L · order²`
/// entries, cell-major: `values[cell · n² + k] = Ŷ_k(cell) · Ω_cell`, where
/// `Ω_cell = 4π / 4^L` sr and `Ŷ_k(cell)` is the average of `Y_k` over the cell, integrated
/// with the centres of its `4 x 4` sub-texels of level `L + 2` (equal solid angles, so the
/// plain mean is the equal-area midpoint rule). So for `f` constant on each cell,
/// `Σ_cell f(cell) · values[cell · n² + k] = ∫ f Y_k dω` up to that 16-point quadrature.
#[derive(Clone, Debug)]
pub struct CellBasis {
    order: u32,
    level: u32,
    values: Vec<f32>,
}

impl CellBasis {
    /// The averaged basis of `order` at cell level `level` (`4^level` cells). Built in
    /// parallel; the values do not depend on the thread count (each cell is independent).
    ///
    /// # Panics
    /// If `order > MAX_ORDER` or `level > MAX_CELL_LEVEL`.
    pub fn new(order: u32, level: u32) -> Self {
        assert!(order <= MAX_ORDER, "order {order} > MAX_ORDER");
        assert!(level <= MAX_CELL_LEVEL, "level {level} > MAX_CELL_LEVEL");
        let n2 = coefficient_count(order);
        let cells = 1usize << (2 * level);
        let mut values = vec![0.0f32; cells * n2];
        if n2 > 0 {
            let sub_res = 1u32 << (level + 2);
            let omega = octahedral::texel_solid_angle(1 << level);
            const SUB: usize = 16;
            values.par_chunks_mut(n2).enumerate().for_each_init(
                || (vec![0.0f64; n2 * SUB], [0.0f64; 5 * SUB]),
                |(ys, scratch), (cell, row)| {
                    let t = octahedral::morton_decode(cell as u32);
                    let (mut x, mut y, mut z) = ([0.0; SUB], [0.0; SUB], [0.0; SUB]);
                    for j in 0..SUB {
                        let sub = UVec2::new(4 * t.x + (j % 4) as u32, 4 * t.y + (j / 4) as u32);
                        let d = octahedral::texel_center(sub, sub_res)
                            .as_dvec3()
                            .normalize();
                        (x[j], y[j], z[j]) = (d.x, d.y, d.z);
                    }
                    eval_batch(order, &x, &y, &z, ys, scratch);
                    for (k, v) in row.iter_mut().enumerate() {
                        let sum: f64 = ys[k * SUB..(k + 1) * SUB].iter().sum();
                        *v = (sum * (omega / SUB as f64)) as f32;
                    }
                },
            );
        }
        CellBasis {
            order,
            level,
            values,
        }
    }

    /// The order (bands `0..order`, `order²` values per cell).
    pub fn order(&self) -> u32 {
        self.order
    }

    /// The cell level: `4^level` cells, the texels of a `2^level` octahedral grid.
    pub fn level(&self) -> u32 {
        self.level
    }

    /// Number of cells, `4^level`.
    pub fn cells(&self) -> usize {
        1usize << (2 * self.level)
    }

    /// The `order²` values of cell `cell` (Morton code at this level):
    /// `Ŷ_k(cell) · Ω_cell`, in steradians.
    ///
    /// # Panics
    /// If `cell >= 4^level`.
    pub fn row(&self, cell: usize) -> &[f32] {
        let n2 = coefficient_count(self.order);
        &self.values[cell * n2..(cell + 1) * n2]
    }

    /// Projects a function constant on each cell: `out[k] = Σ_cell per_cell[cell] ·
    /// row(cell)[k]` (overwrites `out`; units of `per_cell` times sr). Cells with value
    /// exactly zero are skipped (visibility-masked transfers are mostly zero). Accumulates
    /// in `f32` in cell order.
    ///
    /// # Panics
    /// If `per_cell.len() != 4^level` or `out.len() != order²`.
    pub fn project(&self, per_cell: &[f32], out: &mut [f32]) {
        let n2 = coefficient_count(self.order);
        assert_eq!(
            per_cell.len(),
            self.cells(),
            "per_cell must hold 4^level values"
        );
        assert_eq!(out.len(), n2, "out must hold order² values");
        out.fill(0.0);
        if n2 == 0 {
            return;
        }
        for (&f, row) in per_cell.iter().zip(self.values.chunks_exact(n2)) {
            if f == 0.0 {
                continue;
            }
            for (o, &v) in out.iter_mut().zip(row) {
                *o += f * v;
            }
        }
    }
}

/// Texels per batch of [`project_texels`]: the basis values of a batch (`order² · 32` f64,
/// 64 KiB at order 16) stay in the first-level caches.
const BATCH: usize = 32;

/// `Σ_j y[j] · (a, b, c)[j]` with four partial sums per channel in a fixed order, so the
/// compiler may vectorize it and the result is still the same on every run.
#[inline]
fn dot3(y: &[f64], a: &[f64], b: &[f64], c: &[f64]) -> [f64; 3] {
    let mut s = [[0.0f64; 4]; 3];
    let whole = y.len() / 4 * 4;
    for i in (0..whole).step_by(4) {
        for l in 0..4 {
            let v = y[i + l];
            s[0][l] += v * a[i + l];
            s[1][l] += v * b[i + l];
            s[2][l] += v * c[i + l];
        }
    }
    let mut out = [0.0; 3];
    for ch in 0..3 {
        out[ch] = (s[ch][0] + s[ch][1]) + (s[ch][2] + s[ch][3]);
    }
    for i in whole..y.len() {
        out[0] += y[i] * a[i];
        out[1] += y[i] * b[i];
        out[2] += y[i] * c[i];
    }
    out
}

/// Projects an RGB octahedral map onto the basis: `out[k] = Σ_t L(t) Y_k(centre(t)) Ω`, the
/// texel-centre (equal-area midpoint) quadrature of `∫ L Y_k dω`, with `Ω = 4π / res²` sr.
/// `texels` are row-major, texel `(x, y)` at `y · res + x`, as [`crate::lights::EnvMap`]'s
/// `texels()` stores them. Result in the radiance's unit times sr.
///
/// The map's symmetries do seven eighths of the work: the texels `(res-1-x, y)` and
/// `(x, res-1-y)` are a centre's mirror images in `x` and in `z`, and (for an even `res`)
/// `(res/2-1-y, res/2-1-x)` its image in `y` across the equator, and each `Y_k` is even or
/// odd under each of these, so the basis is evaluated at one texel of each group of eight
/// (the triangle `x + y < res/2` of the quadrant `x, y < res/2`) against signed sums of the
/// group's radiances. The representatives' rows are summed in parallel, then added in row
/// order, so the result is bit-identical for any thread count.
/// Centres are computed in `f64` ([`texel_center_f64`]).
///
/// # Panics
/// If `order > MAX_ORDER`, `res == 0` or `texels.len() != res²`.
pub fn project_texels(order: u32, texels: &[[f32; 3]], res: u32) -> Vec<[f64; 3]> {
    assert!(order <= MAX_ORDER, "order {order} > MAX_ORDER");
    assert!(res >= 1, "res must be positive");
    let r = res as usize;
    assert_eq!(texels.len(), r * r, "texels must hold res² values");
    let n2 = coefficient_count(order);
    if n2 == 0 {
        return Vec::new();
    }
    // Class of each coefficient by its parity under x -> -x (bit 0: odd, the m < 0 ones),
    // z -> -z (bit 1: odd; (x' + i y')^m with x' = z flips to (-1)^m times its conjugate,
    // so cos mφ takes (-1)^m and sin mφ takes -(-1)^m) and y -> -y (bit 2: P_l^m is odd
    // when l + m is).
    let mut class = vec![0u8; n2];
    for l in 0..order {
        for m in -(l as i32)..=l as i32 {
            let odd_x = m < 0;
            let odd_z = (m.unsigned_abs() % 2 == 1) != (m < 0);
            let odd_y = (l + m.unsigned_abs()) % 2 == 1;
            class[index(l, m)] = odd_x as u8 | ((odd_z as u8) << 1) | ((odd_y as u8) << 2);
        }
    }
    let half = r.div_ceil(2);
    // With an even side, the texel (half-1-y, half-1-x) of the same quadrant is (x, y)'s
    // image across the equator (the map folds the square's corners over the diagonals):
    // representatives are then the triangle x + y <= half - 1.
    let fold = r.is_multiple_of(2);
    let get = |xx: usize, yy: usize, skip: bool| {
        if skip {
            [0.0; 3]
        } else {
            texels[yy * r + xx].map(f64::from)
        }
    };
    // The four signed sums (by x and z parity) of the mirror group of (x, y) in the
    // quadrant x, y < half. Odd sides have a middle row and column that are their own
    // mirrors, counted once.
    let group = |x: usize, y: usize| -> [[f64; 3]; 4] {
        let (x2, y2) = (r - 1 - x, r - 1 - y);
        let a = get(x, y, false);
        let b = get(x2, y, x2 == x);
        let c = get(x, y2, y2 == y);
        let e = get(x2, y2, x2 == x || y2 == y);
        let mut g = [[0.0; 3]; 4];
        for ch in 0..3 {
            g[0][ch] = (a[ch] + b[ch]) + (c[ch] + e[ch]);
            g[1][ch] = (a[ch] - b[ch]) + (c[ch] - e[ch]);
            g[2][ch] = (a[ch] + b[ch]) - (c[ch] + e[ch]);
            g[3][ch] = (a[ch] - b[ch]) - (c[ch] - e[ch]);
        }
        g
    };
    let rows: Vec<Vec<[f64; 3]>> = (0..half)
        .into_par_iter()
        .map(|y| {
            let width = if fold { half - y } else { half };
            let mut acc = vec![[0.0f64; 3]; n2];
            let mut ys = vec![0.0f64; n2 * BATCH];
            let mut scratch = [0.0f64; 5 * BATCH];
            // Per class, per channel: the signed sum of the radiances of the group.
            let mut w = [[[0.0f64; BATCH]; 3]; 8];
            let (mut dx, mut dy, mut dz) = ([0.0; BATCH], [0.0; BATCH], [0.0; BATCH]);
            for x0 in (0..width).step_by(BATCH) {
                let nb = BATCH.min(width - x0);
                for j in 0..nb {
                    let x = x0 + j;
                    let d = texel_center_f64(UVec2::new(x as u32, y as u32), res);
                    (dx[j], dy[j], dz[j]) = (d.x, d.y, d.z);
                    let ga = group(x, y);
                    // Texels on the equator's diagonal are their own images.
                    let (xf, yf) = (half - 1 - y, half - 1 - x);
                    let gb = if fold && (xf, yf) != (x, y) {
                        group(xf, yf)
                    } else {
                        [[0.0; 3]; 4]
                    };
                    for c in 0..4 {
                        for ch in 0..3 {
                            w[c][ch][j] = ga[c][ch] + gb[c][ch];
                            w[c + 4][ch][j] = ga[c][ch] - gb[c][ch];
                        }
                    }
                }
                eval_batch(
                    order,
                    &dx[..nb],
                    &dy[..nb],
                    &dz[..nb],
                    &mut ys,
                    &mut scratch,
                );
                for (k, a) in acc.iter_mut().enumerate() {
                    let wc = &w[class[k] as usize];
                    let s = dot3(
                        &ys[k * nb..(k + 1) * nb],
                        &wc[0][..nb],
                        &wc[1][..nb],
                        &wc[2][..nb],
                    );
                    for ch in 0..3 {
                        a[ch] += s[ch];
                    }
                }
            }
            acc
        })
        .collect();
    let omega = octahedral::texel_solid_angle(res);
    let mut out = vec![[0.0f64; 3]; n2];
    for row in &rows {
        for (o, s) in out.iter_mut().zip(row) {
            for ch in 0..3 {
                o[ch] += s[ch];
            }
        }
    }
    for o in &mut out {
        for v in o.iter_mut() {
            *v *= omega;
        }
    }
    out
}

/// Largest deviation of `RᵀR` from the identity that [`Rotation::new`] accepts (rotations
/// stored in `f32` are orthonormal to `~1e-7`); the matrix is then snapped to the nearest
/// rotation.
pub const ROTATION_TOLERANCE: f64 = 1e-5;

/// The SH rotation matrices of a 3D rotation, one per band (block-diagonal: bands never
/// mix).
///
/// Semantics: if `c` are the coefficients of `f`, [`Rotation::apply`] gives the coefficients
/// of `f_R(ω) = f(Rᵀ ω)`, the function turned so that a feature at `ω` moves to `R ω`. So
/// rotating the coefficients of a projected map equals projecting the rotated map, and
/// `Rotation::new(a) ∘ Rotation::new(b) = Rotation::new(a · b)`.
///
/// Invariants: `blocks[l]` is the orthogonal `(2l+1) x (2l+1)` matrix of band `l`, row-major,
/// row `m + l`, column `m' + l`: `c'_{l,m} = Σ_{m'} blocks[l][(m+l)(2l+1) + m'+l] c_{l,m'}`.
/// Built by the Ivanic & Ruedenberg recurrence (1996: the coefficients `u, v, w` of their
/// Table 1 and the functions `U, V, W, P` of their Table 2, with the 1998 erratum), exact to rounding in `O(order³)` operations, no numerical projection.
#[derive(Clone, Debug)]
pub struct Rotation {
    order: u32,
    blocks: Vec<Vec<f64>>,
}

impl Rotation {
    /// The SH rotation of `order` for the rotation matrix `r` (acting on column vectors of
    /// the library's frame, `ω ↦ r ω`). `r` must be finite, orthonormal to
    /// [`ROTATION_TOLERANCE`] (max-abs of `rᵀr - I`) and proper (`det r > 0`); it is snapped
    /// to the nearest rotation (its polar factor) before use. Otherwise an
    /// [`Error::InvalidArgument`] names `rotation` (or `order` when `order > MAX_ORDER`).
    pub fn new(order: u32, r: DMat3) -> Result<Self> {
        if order > MAX_ORDER {
            return Err(Error::invalid(
                "order",
                format!("must be at most {MAX_ORDER}, got {order}"),
            ));
        }
        let r = check_rotation(r)?;
        let n = order as usize;
        let mut blocks: Vec<Vec<f64>> = Vec::with_capacity(n);
        if n > 0 {
            blocks.push(vec![1.0]);
        }
        if n > 1 {
            // Band 1 without the Condon–Shortley phase is `c · (y', z', x')` in the SH frame
            // (I&R's order), which is `c · (x, y, z)` in the library's: the coefficients of
            // `a · ω` are `c⁻¹ a`, and those of `a · Rᵀω = (R a) · ω` are `c⁻¹ R a`, so the
            // block is `r` itself.
            let mut b1 = vec![0.0; 9];
            for i in 0..3 {
                for j in 0..3 {
                    b1[i * 3 + j] = r.col(j)[i];
                }
            }
            blocks.push(b1);
        }
        for l in 2..n {
            let b = band_block(l as i32, &blocks[1], &blocks[l - 1]);
            blocks.push(b);
        }
        // The recurrence works in the phase-free basis; ours has (-1)^m on every m.
        for (l, b) in blocks.iter_mut().enumerate() {
            let d = 2 * l + 1;
            for i in 0..d {
                for j in 0..d {
                    if (i + j) % 2 == 1 {
                        b[i * d + j] = -b[i * d + j];
                    }
                }
            }
        }
        Ok(Rotation { order, blocks })
    }

    /// The order (bands `0..order`).
    pub fn order(&self) -> u32 {
        self.order
    }

    /// The `(2l+1)²` row-major matrix of band `l < order` (see the type's invariants).
    pub fn block(&self, l: u32) -> &[f64] {
        &self.blocks[l as usize]
    }

    /// `out = D(R) input`: the coefficients of `f(Rᵀ ω)` from those of `f` (overwrites
    /// `out`).
    ///
    /// # Panics
    /// If `input.len()` or `out.len()` is not `order²`.
    pub fn apply(&self, input: &[f64], out: &mut [f64]) {
        self.apply_with(input, out, |row, x| {
            row.iter().zip(x).map(|(a, v)| a * v).sum()
        });
    }

    /// [`Self::apply`] for RGB coefficients (each channel rotated alike).
    ///
    /// # Panics
    /// If `input.len()` or `out.len()` is not `order²`.
    pub fn apply_rgb(&self, input: &[[f64; 3]], out: &mut [[f64; 3]]) {
        self.apply_with(input, out, |row, x| {
            let mut s = [0.0; 3];
            for (a, v) in row.iter().zip(x) {
                for ch in 0..3 {
                    s[ch] += a * v[ch];
                }
            }
            s
        });
    }

    /// `out = D(R) input` band by band, `dot` one row of a band's block against the band's
    /// input coefficients.
    fn apply_with<T>(&self, input: &[T], out: &mut [T], dot: impl Fn(&[f64], &[T]) -> T) {
        let n2 = coefficient_count(self.order);
        assert_eq!(input.len(), n2, "input must hold order² coefficients");
        assert_eq!(out.len(), n2, "out must hold order² coefficients");
        for (l, b) in self.blocks.iter().enumerate() {
            let d = 2 * l + 1;
            let base = l * l;
            let x = &input[base..base + d];
            for (i, o) in out[base..base + d].iter_mut().enumerate() {
                *o = dot(&b[i * d..(i + 1) * d], x);
            }
        }
    }
}

/// Validates a rotation matrix and returns its polar factor (the nearest rotation).
fn check_rotation(r: DMat3) -> Result<DMat3> {
    if !r.is_finite() {
        return Err(Error::invalid(
            "rotation",
            format!("must be finite, got {r:?}"),
        ));
    }
    let e = r.transpose() * r - DMat3::IDENTITY;
    let dev = e
        .to_cols_array()
        .iter()
        .fold(0.0f64, |a, &v| a.max(v.abs()));
    if dev > ROTATION_TOLERANCE {
        return Err(Error::invalid(
            "rotation",
            format!(
                "must be orthonormal (max |RᵀR - I| <= {ROTATION_TOLERANCE}), got deviation {dev:.3e}"
            ),
        ));
    }
    if r.determinant() <= 0.0 {
        return Err(Error::invalid(
            "rotation",
            "must be a proper rotation (determinant +1), got a reflection",
        ));
    }
    // Newton–Schulz iteration towards the polar factor: converges quadratically from a
    // deviation of 1e-5, so three steps reach rounding.
    let mut q = r;
    for _ in 0..3 {
        q = q * (DMat3::from_diagonal(DVec3::splat(1.5)) - 0.5 * (q.transpose() * q));
    }
    Ok(q)
}

/// Entry `(m, n)` of a band-`l` block stored row-major with centred indices.
#[inline]
fn at(block: &[f64], l: i32, m: i32, n: i32) -> f64 {
    block[((m + l) * (2 * l + 1) + (n + l)) as usize]
}

/// Ivanic & Ruedenberg's `P` (1996, Table 2): `i ∈ {-1, 0, 1}`, `a` a degree of band
/// `l - 1`, `b` one of band `l`.
#[inline]
fn p_term(i: i32, a: i32, b: i32, l: i32, r1: &[f64], prev: &[f64]) -> f64 {
    let lp = l - 1;
    if b == l {
        at(r1, 1, i, 1) * at(prev, lp, a, lp) - at(r1, 1, i, -1) * at(prev, lp, a, -lp)
    } else if b == -l {
        at(r1, 1, i, 1) * at(prev, lp, a, -lp) + at(r1, 1, i, -1) * at(prev, lp, a, lp)
    } else {
        at(r1, 1, i, 0) * at(prev, lp, a, b)
    }
}

/// The block of band `l >= 2` from band 1 and band `l - 1` (phase-free basis):
/// `R^l_{mn} = u U + v V + w W` (I&R 1996, coefficients of Table 1, functions of Table 2,
/// with the erratum's form of `V` at `m < 0`). A term whose coefficient is zero
/// is skipped: its function would index outside band `l - 1`.
fn band_block(l: i32, r1: &[f64], prev: &[f64]) -> Vec<f64> {
    let d = (2 * l + 1) as usize;
    let mut out = vec![0.0; d * d];
    for m in -l..=l {
        for n in -l..=l {
            let delta0 = if m == 0 { 1.0 } else { 0.0 };
            let denom = if n.abs() == l {
                (2 * l * (2 * l - 1)) as f64
            } else {
                ((l + n) * (l - n)) as f64
            };
            let am = m.abs();
            let u = (((l + m) * (l - m)) as f64 / denom).sqrt();
            let v = 0.5
                * ((1.0 + delta0) * ((l + am - 1) * (l + am)) as f64 / denom).sqrt()
                * (1.0 - 2.0 * delta0);
            let w = -0.5 * (((l - am - 1) * (l - am)) as f64 / denom).sqrt() * (1.0 - delta0);
            let mut value = 0.0;
            if u != 0.0 {
                value += u * p_term(0, m, n, l, r1, prev);
            }
            if v != 0.0 {
                let big_v = if m == 0 {
                    p_term(1, 1, n, l, r1, prev) + p_term(-1, -1, n, l, r1, prev)
                } else if m > 0 {
                    let d1: f64 = if m == 1 { 1.0 } else { 0.0 };
                    p_term(1, m - 1, n, l, r1, prev) * (1.0 + d1).sqrt()
                        - if m == 1 {
                            0.0
                        } else {
                            p_term(-1, -m + 1, n, l, r1, prev)
                        }
                } else {
                    let d1: f64 = if m == -1 { 1.0 } else { 0.0 };
                    (if m == -1 {
                        0.0
                    } else {
                        p_term(1, m + 1, n, l, r1, prev)
                    }) + p_term(-1, -m - 1, n, l, r1, prev) * (1.0 + d1).sqrt()
                };
                value += v * big_v;
            }
            if w != 0.0 {
                let big_w = if m > 0 {
                    p_term(1, m + 1, n, l, r1, prev) + p_term(-1, -m - 1, n, l, r1, prev)
                } else {
                    p_term(1, m - 1, n, l, r1, prev) - p_term(-1, -m + 1, n, l, r1, prev)
                };
                value += w * big_w;
            }
            out[((m + l) as usize) * d + (n + l) as usize] = value;
        }
    }
    out
}

#[cfg(test)]
// Tests index several parallel arrays by coefficient.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::sampling::rng::{hash4, to_unit_f64};
    use glam::DQuat;
    use std::f64::consts::PI;

    fn u(seed: u64, i: u64, d: u64) -> f64 {
        to_unit_f64(hash4(seed, i, 0, d))
    }

    fn random_dir(seed: u64, i: u64) -> DVec3 {
        let z = 1.0 - 2.0 * u(seed, i, 0);
        let phi = 2.0 * PI * u(seed, i, 1);
        let r = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(r * phi.cos(), z, r * phi.sin())
    }

    fn random_rotation(seed: u64, i: u64) -> DMat3 {
        // A normalised Gaussian-ish quaternion (sum of uniforms) is enough for a spread.
        let g = |d: u64| (0..4u64).map(|t| u(seed, i, 10 * d + t)).sum::<f64>() - 2.0;
        DMat3::from_quat(DQuat::from_xyzw(g(0), g(1), g(2), g(3)).normalize())
    }

    fn random_coeffs(seed: u64, n2: usize) -> Vec<f64> {
        (0..n2).map(|k| 2.0 * u(seed, k as u64, 7) - 1.0).collect()
    }

    fn band(k: usize) -> f64 {
        (k as f64).sqrt().floor()
    }

    /// `l (l + 1)`, the eigenvalue of `-Δ` on band `l` (`∫ |∇Y_k|² dω`).
    fn lambda(k: usize) -> f64 {
        let l = band(k);
        l * (l + 1.0)
    }

    fn eval_vec(order: u32, d: DVec3) -> Vec<f64> {
        let mut y = vec![0.0; coefficient_count(order)];
        eval(order, d, &mut y);
        y
    }

    fn dot(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(x, y)| x * y).sum()
    }

    fn norm(a: &[f64]) -> f64 {
        dot(a, a).sqrt()
    }

    #[test]
    fn coefficient_indexing() {
        assert_eq!(coefficient_count(0), 0);
        assert_eq!(coefficient_count(MAX_ORDER), 256);
        assert_eq!(index(0, 0), 0);
        assert_eq!(index(1, -1), 1);
        assert_eq!(index(2, 2), 8);
        assert_eq!(index(15, 15), 255);
    }

    #[test]
    fn eval_matches_closed_forms_up_to_band_2() {
        let c0 = 0.5 / PI.sqrt();
        let c1 = (3.0 / (4.0 * PI)).sqrt();
        let c2 = 0.5 * (15.0 / PI).sqrt();
        let c20 = 0.25 * (5.0 / PI).sqrt();
        let c22 = 0.25 * (15.0 / PI).sqrt();
        // The axes (poles included) and random directions.
        let mut dirs = vec![
            DVec3::X,
            DVec3::Y,
            DVec3::Z,
            -DVec3::X,
            -DVec3::Y,
            -DVec3::Z,
        ];
        dirs.extend((0..200).map(|i| random_dir(1, i)));
        for d in dirs {
            let (x, y, z) = (d.x, d.y, d.z);
            let want = [
                c0,
                -c1 * x,
                c1 * y,
                -c1 * z,
                c2 * z * x,
                -c2 * x * y,
                c20 * (3.0 * y * y - 1.0),
                -c2 * y * z,
                c22 * (z * z - x * x),
            ];
            let got = eval_vec(3, d);
            for k in 0..9 {
                assert!(
                    (got[k] - want[k]).abs() < 1e-15,
                    "k {k} at {d}: {} vs {}",
                    got[k],
                    want[k]
                );
            }
            // Lower orders are prefixes of higher ones.
            assert_eq!(&eval_vec(2, d)[..], &got[..4]);
            assert_eq!(&eval_vec(MAX_ORDER, d)[..9], &got[..]);
        }
    }

    /// Gauss-Legendre nodes and weights on [-1, 1] (Newton on the Legendre recurrence).
    fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
        (0..n)
            .map(|i| {
                let mut x = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
                let mut dp = 0.0;
                for _ in 0..100 {
                    let (mut p0, mut p1) = (1.0, x);
                    for k in 2..=n {
                        let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                        p0 = p1;
                        p1 = p2;
                    }
                    dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                    let dx = p1 / dp;
                    x -= dx;
                    if dx.abs() < 1e-16 {
                        break;
                    }
                }
                (x, 2.0 / ((1.0 - x * x) * dp * dp))
            })
            .collect()
    }

    /// All 256 functions of MAX_ORDER are orthonormal under a quadrature that is exact for
    /// their products (16 Gauss-Legendre nodes in cos θ: degree 31; 32 equal steps in φ:
    /// trigonometric degree 31), so the only error is rounding: the recurrences stay
    /// stable up to band 15 (no factorials, no overflow).
    #[test]
    fn eval_is_orthonormal_to_rounding_at_max_order() {
        let order = MAX_ORDER;
        let n2 = coefficient_count(order);
        let nodes = gauss_legendre(16);
        let nphi = 32;
        let mut gram = vec![0.0; n2 * n2];
        let mut y = vec![0.0; n2];
        for &(ct, wt) in &nodes {
            let st = (1.0 - ct * ct).sqrt();
            for i in 0..nphi {
                let phi = 2.0 * PI * (i as f64 + 0.3) / nphi as f64;
                let d = DVec3::new(st * phi.cos(), ct, st * phi.sin());
                eval(order, d, &mut y);
                assert!(y.iter().all(|v| v.is_finite()));
                let w = wt * 2.0 * PI / nphi as f64;
                for k in 0..n2 {
                    for j in 0..n2 {
                        gram[k * n2 + j] += w * y[k] * y[j];
                    }
                }
            }
        }
        for k in 0..n2 {
            for j in 0..n2 {
                let e = gram[k * n2 + j] - if k == j { 1.0 } else { 0.0 };
                assert!(e.abs() < 1e-12, "gram[{k}][{j}] off by {e:e}");
            }
        }
    }

    #[test]
    fn texel_center_f64_is_the_octahedral_map() {
        for res in [1u32, 2, 8, 64] {
            for y in 0..res {
                for x in 0..res {
                    let t = UVec2::new(x, y);
                    let a = texel_center_f64(t, res);
                    let b = octahedral::texel_center(t, res).as_dvec3();
                    assert!((a.length() - 1.0).abs() < 1e-15);
                    // f32's map is accurate to a few ulps of its trigonometry.
                    assert!((a - b).length() < 1e-6, "res {res} texel {t}: {a} vs {b}");
                }
            }
        }
    }

    /// The cell-averaged basis is orthonormal up to the smoothing that averaging over a cell
    /// does: for a cell with second moments `M ≈ κ Ω/12 · I` (κ = 1 for a square),
    /// `Σ Ω Ŷ_k Ŷ_j = δ_kj - Σ Ω Cov_cell(Y_k, Y_j)` and
    /// `|Σ Ω Cov_cell| <= κ Ω/12 · √(∫|∇Y_k|² ∫|∇Y_j|²) = κ Ω/12 · √(λ_k λ_j)`,
    /// `λ = l (l + 1)`. The equal-area cells are at most about twice as spread as squares
    /// (κ = 1.85 measured at levels 4-7), so κ = 2. Band 0 has no variance in a cell; its
    /// error is the 16-point quadrature of `∫ Y_j` on the level-L+2 grid, bounded as in
    /// [`constant_map_projects_to_band_0`] with `Ω/16`. The error is O(Ω): a level finer
    /// divides it by 4.
    #[test]
    fn cell_basis_is_orthonormal_up_to_cell_smoothing() {
        let order = 8;
        let n2 = coefficient_count(order);
        let mut worst = Vec::new();
        for level in [5u32, 6] {
            let basis = CellBasis::new(order, level);
            assert_eq!(
                (basis.order(), basis.level(), basis.cells()),
                (order, level, 1 << (2 * level))
            );
            let omega = octahedral::texel_solid_angle(1 << level);
            let mut max_err: f64 = 0.0;
            for k in 0..n2 {
                for j in 0..n2 {
                    let g: f64 = (0..basis.cells())
                        .map(|c| basis.row(c)[k] as f64 * basis.row(c)[j] as f64)
                        .sum::<f64>()
                        / omega;
                    let e = g - if k == j { 1.0 } else { 0.0 };
                    let tol = if k == 0 || j == 0 {
                        2.0 * (omega / 16.0) / 24.0 * lambda(k.max(j)) * 4.0 * PI * 0.5 / PI.sqrt()
                    } else {
                        2.0 * omega / 12.0 * (lambda(k) * lambda(j)).sqrt()
                    } + 1e-6; // f32 storage of the rows
                    assert!(
                        e.abs() <= tol,
                        "level {level} G[{k}][{j}] - δ = {e:e} > {tol:e}"
                    );
                    if k == j && k > 0 {
                        // Averaging only removes energy.
                        assert!(e < 1e-6, "level {level} G[{k}][{k}] = 1 + {e:e}");
                    }
                    max_err = max_err.max(e.abs());
                }
            }
            worst.push(max_err);
        }
        let ratio = worst[0] / worst[1];
        assert!(
            (3.5..4.5).contains(&ratio),
            "error ratio level 5/6 {ratio} (O(Ω) expects 4)"
        );
        // The level-6 figure the module documentation quotes.
        assert!(worst[1] < 0.025, "max |G - I| at level 6: {}", worst[1]);
    }

    /// Rows are in Morton order: each is close to `Ω Y_k` at its own cell's centre (and not
    /// at another cell's), with the centre-vs-mean difference bounded like the quadrature.
    #[test]
    fn cell_basis_rows_follow_morton_order() {
        let (order, level) = (4u32, 3u32);
        let basis = CellBasis::new(order, level);
        let res = 1u32 << level;
        let omega = octahedral::texel_solid_angle(res);
        for cell in 0..basis.cells() {
            let t = octahedral::morton_decode(cell as u32);
            let y = eval_vec(order, texel_center_f64(t, res));
            let row = basis.row(cell);
            for k in 0..coefficient_count(order) {
                let mean = row[k] as f64 / omega;
                // |mean - centre| <= κ Ω/24 max|∇²Y| with |∇²Y| <= λ max|Y|, max|Y_l| <=
                // √((2l+1)/4π); generous in κ = 2 and the addition theorem's bound.
                let l = band(k);
                let bound = 2.0 * omega / 24.0 * lambda(k) * ((2.0 * l + 1.0) / (4.0 * PI)).sqrt();
                assert!(
                    (mean - y[k]).abs() <= bound * 4.0 + 1e-6,
                    "cell {cell} ({t}) k {k}: mean {mean} vs centre {}",
                    y[k]
                );
            }
        }
        // A swap of two cells would be caught: cells 1 and 2 are (1, 0) and (0, 1).
        assert_eq!(octahedral::morton_decode(1), UVec2::new(1, 0));
        let (r1, r2) = (basis.row(1), basis.row(2));
        // Y_1^{-1} ∝ -x and Y_1^1 ∝ -z: (1, 0) is at larger x than (0, 1) and smaller z.
        assert!(r1[index(1, -1)] < r2[index(1, -1)] && r1[index(1, 1)] > r2[index(1, 1)]);
    }

    #[test]
    fn cell_basis_projection_sums_rows_and_skips_zeros() {
        let (order, level) = (6u32, 3u32);
        let basis = CellBasis::new(order, level);
        let n2 = coefficient_count(order);
        let cells = basis.cells();
        // Mostly zero, like a visibility-masked transfer; one tiny value, one huge.
        let per_cell: Vec<f32> = (0..cells)
            .map(|c| match c % 5 {
                0 => (u(3, c as u64, 0) * 4.0) as f32,
                1 => 1e-30,
                2 if c == 7 => 1e6,
                _ => 0.0,
            })
            .collect();
        let mut out = vec![f32::NAN; n2];
        basis.project(&per_cell, &mut out);
        for k in 0..n2 {
            let want: f64 = (0..cells)
                .map(|c| per_cell[c] as f64 * basis.row(c)[k] as f64)
                .sum();
            let scale: f64 = (0..cells)
                .map(|c| (per_cell[c] as f64 * basis.row(c)[k] as f64).abs())
                .sum();
            // f32 accumulation over `cells` terms.
            let tol = scale * cells as f64 * f32::EPSILON as f64;
            assert!(
                (out[k] as f64 - want).abs() <= tol,
                "k {k}: {} vs {want}",
                out[k]
            );
        }
        // All zero: exactly zero.
        basis.project(&vec![0.0; cells], &mut out);
        assert!(out.iter().all(|&v| v == 0.0));
        // A constant function projects to band 0: √(4π) c, to f32 rounding.
        basis.project(&vec![2.0; cells], &mut out);
        assert!((out[0] as f64 - 2.0 * (4.0 * PI).sqrt()).abs() < 1e-5);
    }

    /// Midpoint-rule bound of `|Σ_t Ω Y_k(centre) - ∫ Y_k|`: per cell the error is
    /// `½ tr(H M)` with `M ≈ κ Ω/12 · Ω I`, so the sum is at most `κ Ω/24 ∫ |ΔY_k| <=
    /// κ Ω/24 λ √(4π)` (Cauchy-Schwarz, `∫ Y² = 1`), κ = 2 as above.
    fn midpoint_bound(k: usize, res: u32) -> f64 {
        2.0 * octahedral::texel_solid_angle(res) / 24.0 * lambda(k) * (4.0 * PI).sqrt()
    }

    #[test]
    fn constant_map_projects_to_band_0() {
        let order = 8;
        let mut worst = Vec::new();
        for res in [1u32, 2, 16, 128, 256] {
            let c = [0.5f32, 1.0, 3.0];
            let tex = vec![c; (res * res) as usize];
            let p = project_texels(order, &tex, res);
            assert_eq!(p.len(), 64);
            for ch in 0..3 {
                let want = c[ch] as f64 * (4.0 * PI).sqrt();
                assert!(
                    ((p[0][ch] - want) / want).abs() < 1e-12,
                    "res {res}: {}",
                    p[0][ch]
                );
                for k in 1..64 {
                    let bound = c[ch] as f64 * midpoint_bound(k, res);
                    assert!(
                        p[k][ch].abs() <= bound.max(1e-14),
                        "res {res} k {k}: {} > {bound}",
                        p[k][ch]
                    );
                }
            }
            worst.push(p[1..].iter().map(|v| v[2].abs()).fold(0.0, f64::max) / p[0][2]);
        }
        // The higher coefficients are midpoint-rule error (3.4e-5 of c0 at res 256, in
        // Y_2^0): they fall by 4 per level.
        let ratio = worst[3] / worst[4];
        assert!((3.5..4.5).contains(&ratio), "res 128/256 ratio {ratio}");
        assert!(worst[4] < 1e-4, "res 256: {:e} of c0", worst[4]);
        // Black maps are exactly zero.
        let p = project_texels(order, &vec![[0.0; 3]; 64], 8);
        assert!(p.iter().all(|v| *v == [0.0; 3]));
    }

    /// One texel at `L` (1e6 above a constant background, or alone): its coefficients are
    /// exactly `L Ω Y_k(centre)`, for texels in every part of the symmetry group of
    /// [`project_texels`] (representative, mirrored in x, z, folded in y, on the diagonal).
    #[test]
    fn single_bright_texel() {
        let order = 12;
        let n2 = coefficient_count(order);
        for res in [1u32, 2, 8, 32] {
            let omega = octahedral::texel_solid_angle(res);
            let background = project_texels(order, &vec![[0.25; 3]; (res * res) as usize], res);
            let picks = [
                (0, 0),
                (res - 1, 0),
                (0, res - 1),
                (res / 2, res / 2),
                (res / 3, res - 1 - res / 5),
            ];
            for (x, y) in picks {
                for (base, bg) in [(0.0f32, None), (0.25, Some(&background))] {
                    let mut tex = vec![[base; 3]; (res * res) as usize];
                    let lum = [1e6f32, 2.0, 0.0];
                    tex[(y * res + x) as usize] = [base + lum[0], base + lum[1], base + lum[2]];
                    let p = project_texels(order, &tex, res);
                    let yc = eval_vec(order, texel_center_f64(UVec2::new(x, y), res));
                    for k in 0..n2 {
                        for ch in 0..3 {
                            let want =
                                lum[ch] as f64 * omega * yc[k] + bg.map_or(0.0, |b| b[k][ch]);
                            let scale = (1e6 + 0.25) * omega * 4.0 * PI;
                            assert!(
                                (p[k][ch] - want).abs() <= 1e-13 * scale,
                                "res {res} texel ({x},{y}) k {k} ch {ch}: {} vs {want}",
                                p[k][ch]
                            );
                        }
                    }
                }
            }
        }
    }

    /// Midpoint bound for the coefficient `k` of a band-limited `f = Σ c_j Y_j` of order
    /// `order_f`: the integrand `g = f Y_k` has bands up to `l_f + l_k`, so
    /// `∫|Δg| <= √(4π) ‖Δg‖₂ <= √(4π) λ(l_f + l_k) ‖g‖₂` and
    /// `‖g‖₂ <= max|Y_k| ‖c‖₂ = √((2 l_k + 1) / 4π) ‖c‖₂`; times κ Ω/24 as in
    /// [`midpoint_bound`].
    fn product_bound(k: usize, order_f: u32, c_norm: f64, res: u32) -> f64 {
        let l = band(k) + order_f as f64 - 1.0;
        2.0 * octahedral::texel_solid_angle(res) / 24.0
            * l
            * (l + 1.0)
            * (2.0 * band(k) + 1.0).sqrt()
            * c_norm
    }

    /// The map of `Σ_ch c[ch]_k Y_k(Rᵀ ω)` sampled at the texel centres, as `f32` radiance.
    fn sampled_map(order: u32, c: &[Vec<f64>], r: DMat3, res: u32) -> Vec<[f32; 3]> {
        let mut tex = vec![[0.0f32; 3]; (res * res) as usize];
        for y in 0..res {
            for x in 0..res {
                let yv = eval_vec(
                    order,
                    r.transpose() * texel_center_f64(UVec2::new(x, y), res),
                );
                for ch in 0..3 {
                    tex[(y * res + x) as usize][ch] = dot(&c[ch], &yv) as f32;
                }
            }
        }
        tex
    }

    /// `f = Σ c_k Y_k` of order 4, sampled at the texel centres of a level-7 grid (128²),
    /// projects back to `c` within [`product_bound`] (plus the `f32` rounding of the
    /// samples), and the error is quadrature error: it falls by 4 from the level-6 grid.
    /// Through the cell basis (sampled at cell centres, projected with cell averages) the
    /// error is the centre-vs-mean of `f` plus the in-cell covariance of `f` and `Y_k`.
    #[test]
    fn band_limited_function_projects_back_to_its_coefficients() {
        let (order, level) = (4u32, 7u32);
        let n2 = coefficient_count(order);
        let coeffs: Vec<Vec<f64>> = (0..3).map(|ch| random_coeffs(20 + ch, n2)).collect();
        let c_norm: Vec<f64> = coeffs.iter().map(|c| norm(c)).collect();
        let mut worst = Vec::new();
        for res in [64u32, 128] {
            let p = project_texels(
                order,
                &sampled_map(order, &coeffs, DMat3::IDENTITY, res),
                res,
            );
            let mut w: f64 = 0.0;
            for k in 0..n2 {
                for ch in 0..3 {
                    // f32 samples: relative 6e-8 of |f| <= ‖c‖₂ √(order²/4π) (addition theorem).
                    let tol = product_bound(k, order, c_norm[ch], res) + 1e-7 * c_norm[ch];
                    let e = (p[k][ch] - coeffs[ch][k]).abs();
                    assert!(
                        e <= tol,
                        "res {res} k {k} ch {ch}: {} vs {} (tol {tol:e})",
                        p[k][ch],
                        coeffs[ch][k]
                    );
                    w = w.max(e / c_norm[ch]);
                }
            }
            worst.push(w);
        }
        let ratio = worst[0] / worst[1];
        assert!(
            (3.5..4.5).contains(&ratio),
            "error ratio res 64/128 {ratio} (O(Ω) expects 4)"
        );

        let res = 1u32 << level;
        let omega = octahedral::texel_solid_angle(res);
        let basis = CellBasis::new(order, level);
        let per_cell: Vec<f32> = (0..basis.cells())
            .map(|c| {
                let t = octahedral::morton_decode(c as u32);
                dot(&coeffs[0], &eval_vec(order, texel_center_f64(t, res))) as f32
            })
            .collect();
        let mut q = vec![0.0f32; n2];
        basis.project(&per_cell, &mut q);
        let lam_f = ((order - 1) * order) as f64;
        for k in 0..n2 {
            // Centre vs mean of f in a cell: κΩ/24 |Δf| summed against Ŷ_k Ω, at most
            // κΩ/24 λ_f ‖c‖₂ (Cauchy-Schwarz); covariance: κΩ/12 √(λ_f λ_k) ‖c‖₂.
            let tol = (2.0 * omega / 24.0 * lam_f
                + 2.0 * omega / 12.0 * (lam_f * lambda(k)).sqrt())
                * c_norm[0]
                + 1e-5 * c_norm[0];
            let e = (q[k] as f64 - coeffs[0][k]).abs();
            assert!(
                e <= tol,
                "cell basis k {k}: {} vs {} (tol {tol:e})",
                q[k],
                coeffs[0][k]
            );
        }
    }

    #[test]
    fn project_texels_is_bit_identical_for_any_thread_count() {
        let res = 64u32;
        let tex: Vec<[f32; 3]> = (0..res * res)
            .map(|i| {
                let v = u(9, i as u64, 0);
                [
                    v as f32,
                    (v * v) as f32 * 100.0,
                    if i % 7 == 0 { 1e5 } else { 0.0 },
                ]
            })
            .collect();
        for order in [1u32, 5, 12] {
            let one = crate::parallel::with_threads(Some(1), || project_texels(order, &tex, res))
                .unwrap();
            let two = crate::parallel::with_threads(Some(2), || project_texels(order, &tex, res))
                .unwrap();
            let bits = |p: &[[f64; 3]]| {
                p.iter()
                    .flat_map(|v| v.map(f64::to_bits))
                    .collect::<Vec<_>>()
            };
            assert_eq!(bits(&one), bits(&two), "order {order}");
        }
        let one = crate::parallel::with_threads(Some(1), || CellBasis::new(6, 4)).unwrap();
        let two = crate::parallel::with_threads(Some(2), || CellBasis::new(6, 4)).unwrap();
        for c in 0..one.cells() {
            let b = |r: &[f32]| r.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(b(one.row(c)), b(two.row(c)));
        }
    }

    fn assert_blocks_close(a: &Rotation, b: &Rotation, tol: f64, what: &str) {
        for l in 0..a.order() {
            for (i, (x, y)) in a.block(l).iter().zip(b.block(l)).enumerate() {
                assert!(
                    (x - y).abs() <= tol,
                    "{what}: band {l} entry {i}: {x} vs {y}"
                );
            }
        }
    }

    fn identity(order: u32) -> Rotation {
        let blocks = (0..order as usize)
            .map(|l| {
                let d = 2 * l + 1;
                (0..d * d)
                    .map(|i| if i / d == i % d { 1.0 } else { 0.0 })
                    .collect()
            })
            .collect();
        Rotation { order, blocks }
    }

    #[test]
    fn rotation_identity_and_full_turns() {
        let order = MAX_ORDER;
        let id = Rotation::new(order, DMat3::IDENTITY).unwrap();
        assert_blocks_close(&id, &identity(order), 1e-15, "identity");
        for axis in [DVec3::Y, DVec3::X, DVec3::new(1.0, 2.0, -0.5).normalize()] {
            let turn = Rotation::new(order, DMat3::from_axis_angle(axis, 2.0 * PI)).unwrap();
            assert_blocks_close(&turn, &identity(order), 1e-9, "360 degrees");
        }
    }

    /// Every block is orthogonal, and a rotation about +y (the SH polar axis) only mixes m
    /// with -m, as the module's frame convention says.
    #[test]
    fn rotation_blocks_are_orthogonal_and_y_turns_keep_m() {
        let order = 12;
        let rot = Rotation::new(order, random_rotation(4, 0)).unwrap();
        for l in 0..order {
            let d = (2 * l + 1) as usize;
            let b = rot.block(l);
            for i in 0..d {
                for j in 0..d {
                    let s: f64 = (0..d).map(|t| b[i * d + t] * b[j * d + t]).sum();
                    let want = if i == j { 1.0 } else { 0.0 };
                    assert!((s - want).abs() < 1e-12, "band {l} ({i},{j}): {s}");
                }
            }
        }
        let angle = 0.7;
        let rot = Rotation::new(order, DMat3::from_rotation_y(angle)).unwrap();
        for l in 0..order {
            let d = (2 * l + 1) as usize;
            let li = l as i32;
            for i in 0..d {
                for j in 0..d {
                    let (m, mp) = (i as i32 - li, j as i32 - li);
                    let v = rot.block(l)[i * d + j];
                    if m.abs() != mp.abs() {
                        assert!(v.abs() < 1e-12, "band {l} ({m},{mp}) = {v}");
                    } else if m == mp {
                        // φ is measured from +z towards +x, which a +y turn by α advances by α.
                        assert!(
                            (v - (m as f64 * angle).cos()).abs() < 1e-12,
                            "band {l} diag {m}: {v}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn rotation_composes() {
        let order = 12;
        for i in 0..5 {
            let (a, b) = (random_rotation(5, 2 * i), random_rotation(5, 2 * i + 1));
            let (ra, rb) = (
                Rotation::new(order, a).unwrap(),
                Rotation::new(order, b).unwrap(),
            );
            let rab = Rotation::new(order, a * b).unwrap();
            let mut prod = identity(order);
            for l in 0..order as usize {
                let d = 2 * l + 1;
                let (x, y) = (&ra.blocks[l], &rb.blocks[l]);
                for r in 0..d {
                    for c in 0..d {
                        prod.blocks[l][r * d + c] =
                            (0..d).map(|t| x[r * d + t] * y[t * d + c]).sum();
                    }
                }
            }
            assert_blocks_close(&prod, &rab, 1e-9, "D(a) D(b) vs D(ab)");
        }
    }

    /// The semantics: the rotated coefficients describe `f_R(ω) = f(Rᵀ ω)`, so
    /// `f_R(R d) = f(d)` for every direction `d`.
    #[test]
    fn rotation_moves_features_from_d_to_r_d() {
        for order in [1u32, 2, 3, 5, 8, 12, MAX_ORDER] {
            let n2 = coefficient_count(order);
            for i in 0..8 {
                let r = random_rotation(6 + order as u64, i);
                let rot = Rotation::new(order, r).unwrap();
                let c = random_coeffs(100 * order as u64 + i, n2);
                let mut cr = vec![0.0; n2];
                rot.apply(&c, &mut cr);
                // RGB form agrees bit for bit on each channel.
                let rgb: Vec<[f64; 3]> = c.iter().map(|&v| [v, -2.0 * v, 0.0]).collect();
                let mut out = vec![[0.0; 3]; n2];
                rot.apply_rgb(&rgb, &mut out);
                for k in 0..n2 {
                    assert_eq!(out[k][0].to_bits(), cr[k].to_bits());
                    assert_eq!(out[k][1], -2.0 * cr[k]);
                }
                for j in 0..16 {
                    let d = random_dir(7, 16 * i + j);
                    let before = eval_vec(order, d);
                    let after = eval_vec(order, r * d);
                    let (f, fr) = (dot(&c, &before), dot(&cr, &after));
                    let scale = norm(&c) * norm(&before);
                    assert!(
                        (f - fr).abs() <= 1e-8 * scale,
                        "order {order}: f(d) {f} vs f_R(R d) {fr} (scale {scale})"
                    );
                }
            }
        }
    }

    /// Rotating the projection of a smooth map equals projecting the rotated map
    /// (`L_R(ω) = L(Rᵀ ω)`): both are within [`product_bound`] of the exactly rotated
    /// coefficients, and their difference is quadrature error (falls by 4 per level).
    #[test]
    fn rotating_a_projection_equals_projecting_the_rotated_map() {
        let order = 4u32;
        let n2 = coefficient_count(order);
        let mut c: Vec<Vec<f64>> = (0..3).map(|ch| random_coeffs(40 + ch, n2)).collect();
        for cc in &mut c {
            cc[0] = 8.0; // a positive radiance
        }
        let r = DMat3::from_axis_angle(DVec3::new(0.3, 1.0, -0.2).normalize(), 2.4);
        let rot = Rotation::new(order, r).unwrap();
        let mut worst = Vec::new();
        for res in [64u32, 128] {
            let p = project_texels(order, &sampled_map(order, &c, DMat3::IDENTITY, res), res);
            let q = project_texels(order, &sampled_map(order, &c, r, res), res);
            let mut rp = vec![[0.0; 3]; n2];
            rot.apply_rgb(&p, &mut rp);
            let mut w: f64 = 0.0;
            for ch in 0..3 {
                let mut exact_r = vec![0.0; n2];
                rot.apply(&c[ch], &mut exact_r);
                let cn = norm(&c[ch]);
                for k in 0..n2 {
                    let tol = product_bound(k, order, cn, res) + 1e-7 * cn;
                    assert!(
                        (q[k][ch] - exact_r[k]).abs() <= tol,
                        "res {res}: rotated map k {k}"
                    );
                    // D is orthogonal, so the rotated projection's error is the original's,
                    // spread over the band: bounded by the band's largest bound.
                    let l = band(k) as usize;
                    let tol_band = product_bound(l * l + 2 * l, order, cn, res) + 1e-7 * cn;
                    assert!(
                        (rp[k][ch] - exact_r[k]).abs() <= tol_band,
                        "res {res}: rotated projection k {k}"
                    );
                    w = w.max((rp[k][ch] - q[k][ch]).abs() / cn);
                }
            }
            worst.push(w);
        }
        let ratio = worst[0] / worst[1];
        assert!(
            (3.5..4.5).contains(&ratio),
            "difference ratio res 64/128 {ratio} (O(Ω) expects 4)"
        );
        assert!(
            worst[1] < 1e-3,
            "rotated projection vs projected rotation {:e}",
            worst[1]
        );
    }

    #[test]
    fn bad_rotations_are_refused_naming_rotation() {
        let bad = [
            DMat3::IDENTITY * 2.0,
            DMat3::from_cols(DVec3::X, DVec3::new(0.1, 1.0, 0.0), DVec3::Z),
            DMat3::from_cols(DVec3::X, DVec3::Y, DVec3::new(0.0, 0.0, f64::NAN)),
            DMat3::from_cols(DVec3::X, DVec3::Y, DVec3::new(0.0, f64::INFINITY, 1.0)),
            DMat3::from_diagonal(DVec3::new(1.0, 1.0, -1.0)),
            DMat3::ZERO,
        ];
        for m in bad {
            let err = Rotation::new(4, m).unwrap_err();
            assert!(
                matches!(&err, Error::InvalidArgument { name, .. } if name == "rotation"),
                "{err}"
            );
            assert!(err.to_string().starts_with("rotation: "), "{err}");
        }
        let err = Rotation::new(MAX_ORDER + 1, DMat3::IDENTITY).unwrap_err();
        assert!(err.to_string().starts_with("order: "), "{err}");
        // A rotation rounded to f32 is accepted and snapped back to an exact one.
        let r = random_rotation(8, 0);
        let r32 = r.as_mat3().as_dmat3();
        let a = Rotation::new(8, r32).unwrap();
        let b = Rotation::new(8, r).unwrap();
        assert_blocks_close(&a, &b, 1e-6, "f32-rounded rotation");
        for l in 0..8 {
            let d = (2 * l + 1) as usize;
            let bl = a.block(l);
            for i in 0..d {
                let s: f64 = (0..d).map(|t| bl[i * d + t] * bl[i * d + t]).sum();
                assert!((s - 1.0).abs() < 1e-13, "band {l} row {i} norm {s}");
            }
        }
    }

    /// Timings for the record (release build): `cargo test --release sh::tests::timings --
    /// --ignored --nocapture`.
    #[test]
    #[ignore]
    fn timings() {
        use std::time::Instant;
        // The machine is shared: the fastest of several runs is the figure least disturbed.
        fn best_ms(reps: usize, mut f: impl FnMut()) -> f64 {
            (0..reps)
                .map(|_| {
                    let t = Instant::now();
                    f();
                    t.elapsed().as_secs_f64() * 1e3
                })
                .fold(f64::INFINITY, f64::min)
        }
        for res in [256u32, 512] {
            let tex: Vec<[f32; 3]> = (0..res * res)
                .map(|i| [u(1, i as u64, 0) as f32; 3])
                .collect();
            for order in [4u32, 8, 12] {
                let run = || {
                    std::hint::black_box(project_texels(order, std::hint::black_box(&tex), res));
                };
                let ms = best_ms(20, run);
                let ms1 = crate::parallel::with_threads(Some(1), || best_ms(20, run)).unwrap();
                println!(
                    "project_texels res {res} order {order}: {ms:.2} ms ({ms1:.2} ms on 1 thread)"
                );
            }
        }
        for level in [4u32, 5] {
            let t = Instant::now();
            let basis = CellBasis::new(8, level);
            let build = t.elapsed().as_secs_f64() * 1e3;
            let per_cell: Vec<f32> = (0..basis.cells())
                .map(|c| u(2, c as u64, 0) as f32)
                .collect();
            let mut out = vec![0.0f32; 64];
            let reps = 20000;
            let t = Instant::now();
            for _ in 0..reps {
                basis.project(std::hint::black_box(&per_cell), &mut out);
                std::hint::black_box(&out);
            }
            let us = t.elapsed().as_secs_f64() * 1e6 / reps as f64;
            println!("CellBasis order 8 level {level}: build {build:.1} ms, project {us:.2} us");
        }
        let t = Instant::now();
        let reps = 1000;
        for i in 0..reps {
            std::hint::black_box(Rotation::new(MAX_ORDER, random_rotation(3, i)).unwrap());
        }
        println!(
            "Rotation::new order 16: {:.1} us",
            t.elapsed().as_secs_f64() * 1e6 / reps as f64
        );
    }
}
