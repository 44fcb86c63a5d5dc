//! Orthonormal 2D Haar wavelets over an octahedral quadtree (the non-standard
//! decomposition of Ng, Ramamoorthi and Hanrahan 2003, "All-frequency shadows using
//! non-linear wavelet lighting approximation", §4.1), for cells in Morton order.
//!
//! The equal-area octahedral map gives every cell of a level the same solid angle, so the
//! plain Haar basis on the square is orthonormal over the sphere up to one constant: the
//! dot product of two functions' cell vectors equals the dot product of their wavelet
//! coefficients ([`forward`] is an orthogonal matrix). A transfer vector truncated to its
//! largest coefficients is then its best approximation in that norm.
//!
//! Layout of the `4^L` coefficients of a level-`L` vector: index 0 is the scaling
//! coefficient of the root; the three details of node `j` (Morton) of level `l < L` sit at
//! `4^l + 3 j + k`, `k ∈ 0..3`, so level `l`'s details fill `[4^l, 4^(l+1))`.

/// One step: the four children `c` (Morton: `(0,0), (1,0), (0,1), (1,1)`) to the parent's
/// scaling coefficient and three details (an orthogonal 4 x 4 matrix, its own inverse).
#[inline]
fn split(c: [f64; 4]) -> (f64, [f64; 3]) {
    let (a, b) = (c[0] + c[1], c[2] + c[3]);
    let (d, e) = (c[0] - c[1], c[2] - c[3]);
    (0.5 * (a + b), [0.5 * (d + e), 0.5 * (a - b), 0.5 * (d - e)])
}

/// The inverse of [`split`].
#[inline]
fn merge(s: f64, d: [f64; 3]) -> [f64; 4] {
    let (a, b) = (s + d[1], s - d[1]);
    let (x, y) = (d[0] + d[2], d[0] - d[2]);
    [0.5 * (a + x), 0.5 * (a - x), 0.5 * (b + y), 0.5 * (b - y)]
}

/// Level `L` of a vector of `4^L` values; `None` when the length is not a power of four.
pub fn level_of(len: usize) -> Option<u32> {
    (len.is_power_of_two() && len.trailing_zeros().is_multiple_of(2))
        .then(|| len.trailing_zeros() / 2)
}

/// Replaces the cell values `v` (Morton order, `4^L` of them) by their Haar coefficients
/// (module docs for the layout). `scratch` must be as long as `v`.
///
/// # Panics
/// When `v.len()` is not a power of four or `scratch` is shorter than `v`.
pub fn forward(v: &mut [f64], scratch: &mut [f64]) {
    let level = level_of(v.len()).expect("4^L values");
    // The scaling coefficients of level l + 1 fill v[..4^(l+1)]; a pass turns them into
    // level l's scaling coefficients and details, in the same span.
    for l in (0..level).rev() {
        let parents = 1usize << (2 * l);
        for j in 0..parents {
            let (s, d) = split([v[4 * j], v[4 * j + 1], v[4 * j + 2], v[4 * j + 3]]);
            scratch[j] = s;
            scratch[parents + 3 * j..parents + 3 * j + 3].copy_from_slice(&d);
        }
        v[..4 * parents].copy_from_slice(&scratch[..4 * parents]);
    }
}

/// The inverse of [`forward`]: coefficients back to cell values (`scratch` as long as `c`).
pub fn inverse(c: &mut [f64], scratch: &mut [f64]) {
    let level = level_of(c.len()).expect("4^L values");
    for l in 0..level {
        let parents = 1usize << (2 * l);
        scratch[..4 * parents].copy_from_slice(&c[..4 * parents]);
        for j in 0..parents {
            let d = [
                scratch[parents + 3 * j],
                scratch[parents + 3 * j + 1],
                scratch[parents + 3 * j + 2],
            ];
            c[4 * j..4 * j + 4].copy_from_slice(&merge(scratch[j], d));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::{hash4, to_unit_f64};

    fn random(n: usize, seed: u64) -> Vec<f64> {
        (0..n)
            .map(|i| to_unit_f64(hash4(seed, i as u64, 0, 0)) * 2.0 - 1.0)
            .collect()
    }

    #[test]
    fn forward_then_inverse_is_the_identity() {
        for level in 0..=6 {
            let n = 1usize << (2 * level);
            let v = random(n, level as u64);
            let mut c = v.clone();
            let mut scratch = vec![0.0; n];
            forward(&mut c, &mut scratch);
            inverse(&mut c, &mut scratch);
            for (a, b) in c.iter().zip(&v) {
                assert!((a - b).abs() < 1e-12, "level {level}: {a} vs {b}");
            }
        }
    }

    /// Orthogonality: dot products and norms survive the transform, and one basis
    /// function (a unit coefficient) inverts to a vector of unit norm.
    #[test]
    fn transform_is_orthogonal() {
        let n = 1 << 8;
        let (a, b) = (random(n, 1), random(n, 2));
        let dot = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(p, q)| p * q).sum::<f64>();
        let (mut ha, mut hb, mut s) = (a.clone(), b.clone(), vec![0.0; n]);
        forward(&mut ha, &mut s);
        forward(&mut hb, &mut s);
        assert!((dot(&a, &b) - dot(&ha, &hb)).abs() < 1e-11);
        for k in [0, 1, 5, 17, 100, 255] {
            let mut e = vec![0.0; n];
            e[k] = 1.0;
            inverse(&mut e, &mut s);
            assert!((dot(&e, &e) - 1.0).abs() < 1e-12, "basis function {k}");
        }
    }

    /// Known answers: a constant has only a scaling coefficient (`c · 2^L`), and one bright
    /// cell's coefficients are the basis functions' values there.
    #[test]
    fn known_coefficients() {
        let level: u32 = 3;
        let n = 1 << (2 * level);
        let mut s = vec![0.0; n];
        let mut c = vec![0.5; n];
        forward(&mut c, &mut s);
        assert!((c[0] - 0.5 * 8.0).abs() < 1e-12);
        assert!(c[1..].iter().all(|x| x.abs() < 1e-12));
        // One cell: every level's node above it has one non-zero set of details of
        // magnitude 2^-(L-l) (the basis function's height at that level).
        let cell = 37;
        let mut v = vec![0.0; n];
        v[cell] = 1.0;
        forward(&mut v, &mut s);
        assert!((v[0] - 1.0 / 8.0).abs() < 1e-12);
        for l in 0..level {
            let node = cell >> (2 * (level - l));
            let height = 0.5f64.powi((level - l) as i32);
            for k in 0..3 {
                let x = v[(1 << (2 * l)) + 3 * node + k];
                assert!(
                    (x.abs() - height).abs() < 1e-12,
                    "level {l} detail {k}: {x}"
                );
            }
        }
        let nonzero = v.iter().filter(|x| x.abs() > 1e-12).count();
        assert_eq!(nonzero, 1 + 3 * level as usize);
    }
}
