//! The pixel's accumulator every pass-layer method adds its samples to: centred sums of
//! the plain estimate `Z` and of a zero-mean control term `W`, from which the estimate
//! `mean(Z − α W)` and the variance of that mean follow for any `α` (CAM08 eq. 3; `W = 0`
//! and `α = 0` for the methods without a control variate), and `α` estimated per pixel from
//! its neighbours' sums (CAM08 §5.4's `α = Cov(Z, W) / Var(W)`, pooled over a window).

use glam::Vec3;

use crate::visibility::cache::interpolant::ALPHA_MAX;

/// What the pass layer needs of a pixel's accumulator.
pub trait PixelSums: Default + Clone + Send + Sync {
    /// Samples added so far.
    fn samples(&self) -> u32;

    /// Whether a pass that brings the pixel to `target` samples shades it: when it has
    /// fewer, by default. A method whose pixels have work to do once, before and apart
    /// from their samples (the relighter's first visit: what the pixel sees, its `⟨V⟩` and
    /// `LB`-samples), says yes at the target too until that is done; the pass then shades
    /// the pixel with no sample.
    fn due(&self, target: u32) -> bool {
        self.samples() < target
    }
}

impl PixelSums for CvSums {
    fn samples(&self) -> u32 {
        self.n
    }
}

/// Centred sums of one pixel's samples of `Z` (the plain estimate) and `W` (the control
/// variate's zero-mean term `g/p − J`), per channel, from which the estimate and its
/// variance follow for any `α` ([`Self::estimate`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CvSums {
    /// Samples.
    pub n: u32,
    pub z: [f64; 3],
    pub w: [f64; 3],
    pub zz: [f64; 3],
    pub ww: [f64; 3],
    pub zw: [f64; 3],
}

impl CvSums {
    /// Adds one sample.
    #[inline]
    pub fn add(&mut self, z: Vec3, w: [f64; 3]) {
        self.n += 1;
        for c in 0..3 {
            let zc = z[c] as f64;
            self.z[c] += zc;
            self.w[c] += w[c];
            self.zz[c] += zc * zc;
            self.ww[c] += w[c] * w[c];
            self.zw[c] += zc * w[c];
        }
    }

    /// `(Σ (z−z̄)(w−w̄), Σ (w−w̄)²)` of channel `c`: what [`neighbour_alphas`] pools.
    pub fn centred(&self, c: usize) -> (f64, f64) {
        if self.n == 0 {
            return (0.0, 0.0);
        }
        let n = self.n as f64;
        let cov = self.zw[c] - self.z[c] * self.w[c] / n;
        let var = (self.ww[c] - self.w[c] * self.w[c] / n).max(0.0);
        (cov, var)
    }

    /// Mean of `Z − α W` per channel and the variance of that mean (`inf` below two
    /// samples, `NaN`-free: 0 samples give mean 0).
    pub fn estimate(&self, alpha: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let n = self.n as f64;
        let mut mean = [0.0; 3];
        let mut var = [f64::INFINITY; 3];
        for c in 0..3 {
            let a = alpha[c];
            let sy = self.z[c] - a * self.w[c];
            if self.n > 0 {
                mean[c] = sy / n;
            }
            if self.n >= 2 {
                let syy = self.zz[c] - 2.0 * a * self.zw[c] + a * a * self.ww[c];
                var[c] = ((syy - sy * sy / n) / (n - 1.0)).max(0.0) / n;
            }
        }
        (mean, var)
    }
}

/// Per-pixel `α` of `AlphaRule::Neighbours` ([`crate::estimators::control_variate::AlphaRule`]) over a `width x height` image of sums
/// (row-major): for each pixel and channel, the window's pooled centred covariance over its
/// pooled centred variance, the pixel itself excluded, clamped to `[0, ALPHA_MAX]`; `1`
/// where the window has no variance (the control variate is then constant and `α` does
/// not matter). The window sums are formed directly, never as a total minus the pixel's
/// own term, so not even rounding ties a pixel's `α` to its own samples.
pub fn neighbour_alphas(
    sums: &[CvSums],
    width: usize,
    height: usize,
    radius: u32,
) -> Vec<[f64; 3]> {
    use rayon::prelude::*;
    debug_assert_eq!(sums.len(), width * height);
    let r = radius as usize;
    let centred: Vec<[(f64, f64); 3]> = sums
        .iter()
        .map(|s| std::array::from_fn(|c| s.centred(c)))
        .collect();
    let mut out = vec![[1.0f64; 3]; sums.len()];
    out.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(height));
            for (x, alpha) in row.iter_mut().enumerate() {
                let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(width));
                let mut pooled = [(0.0f64, 0.0f64); 3];
                for yy in y0..y1 {
                    for xx in x0..x1 {
                        if (xx, yy) == (x, y) {
                            continue;
                        }
                        for (p, q) in pooled.iter_mut().zip(&centred[yy * width + xx]) {
                            p.0 += q.0;
                            p.1 += q.1;
                        }
                    }
                }
                for (a, (cov, var)) in alpha.iter_mut().zip(pooled) {
                    if var > 0.0 {
                        *a = (cov / var).clamp(0.0, ALPHA_MAX);
                    }
                }
            }
        });
    out
}

/// Each pixel's estimate and the variance of that mean with weights `alpha`
/// ([`CvSums::estimate`]), as `f32`.
pub fn resolve(sums: &[CvSums], alpha: &[[f64; 3]]) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let mut image = Vec::with_capacity(sums.len());
    let mut variance = Vec::with_capacity(sums.len());
    for (s, a) in sums.iter().zip(alpha) {
        let (mean, var) = s.estimate(*a);
        image.push(mean.map(|v| v as f32));
        variance.push(var.map(|v| v as f32));
    }
    (image, variance)
}

#[cfg(test)]
mod tests;
