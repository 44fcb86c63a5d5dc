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
mod tests;
