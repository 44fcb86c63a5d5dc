use super::*;
use crate::sampling::rng::{hash4, to_unit_f64};

#[test]
fn cv_sums_give_the_mean_and_variance_of_z_minus_alpha_w() {
    let samples: Vec<(Vec3, [f64; 3])> = (0..50u64)
        .map(|i| {
            let a = to_unit_f64(hash4(1, i, 0, 0));
            let b = to_unit_f64(hash4(1, i, 0, 1));
            (
                Vec3::new(a as f32, 2.0 * a as f32, 0.0),
                [a - 0.5 + 0.1 * b, b, 0.0],
            )
        })
        .collect();
    let mut sums = CvSums::default();
    for (z, w) in &samples {
        sums.add(*z, *w);
    }
    for alpha in [0.0, 0.7, 1.0, 2.0] {
        let (mean, var) = sums.estimate([alpha; 3]);
        for c in 0..3 {
            let y: Vec<f64> = samples
                .iter()
                .map(|(z, w)| z[c] as f64 - alpha * w[c])
                .collect();
            let n = y.len() as f64;
            let m = y.iter().sum::<f64>() / n;
            let v = y.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (n - 1.0) / n;
            assert!((mean[c] - m).abs() < 1e-12 && (var[c] - v).abs() < 1e-12 * (1.0 + v));
        }
    }
    // Channel 2: Z = 0 and W = 0, so zero variance, never negative or NaN.
    assert_eq!(sums.estimate([1.0; 3]).1[2], 0.0);
    let one = {
        let mut s = CvSums::default();
        s.add(Vec3::ONE, [1.0; 3]);
        s
    };
    assert!(one.estimate([1.0; 3]).1.iter().all(|v| v.is_infinite()));
    assert_eq!(CvSums::default().estimate([1.0; 3]).0, [0.0; 3]);
}

#[test]
fn neighbour_alphas_pool_the_window_without_the_pixel() {
    let (w, h) = (7usize, 5usize);
    let sums: Vec<CvSums> = (0..w * h)
        .map(|i| {
            let mut s = CvSums::default();
            for k in 0..6u64 {
                let a = to_unit_f64(hash4(9, i as u64, k, 0));
                let b = to_unit_f64(hash4(9, i as u64, k, 1));
                // Z = 0.8 W + noise in channel 0; W constant in channel 1.
                s.add(Vec3::new((0.8 * a + 0.3 * b) as f32, 1.0, 0.0), [a, 0.0, a]);
            }
            s
        })
        .collect();
    let alphas = neighbour_alphas(&sums, w, h, 2);
    for y in 0..h {
        for x in 0..w {
            let (mut cov, mut var) = (0.0, 0.0);
            for yy in y.saturating_sub(2)..(y + 3).min(h) {
                for xx in x.saturating_sub(2)..(x + 3).min(w) {
                    if (xx, yy) != (x, y) {
                        let (c, v) = sums[yy * w + xx].centred(0);
                        cov += c;
                        var += v;
                    }
                }
            }
            let a = alphas[y * w + x];
            assert!((a[0] - (cov / var).clamp(0.0, ALPHA_MAX)).abs() < 1e-12);
            assert_eq!(a[1], 1.0, "no variance in W: alpha does not matter");
            assert_eq!(a[2], 0.0, "Z = 0 is uncorrelated with W");
        }
    }
    // A pixel's own samples do not move its alpha.
    let mut changed = sums.clone();
    changed[2 * w + 3].add(Vec3::splat(1e6), [1e6; 3]);
    let again = neighbour_alphas(&changed, w, h, 2);
    assert_eq!(again[2 * w + 3], alphas[2 * w + 3]);
    assert_ne!(again[2 * w + 4], alphas[2 * w + 4]);
    // Clamped: perfectly anti-correlated neighbours give 0, steep ones ALPHA_MAX.
    let steep: Vec<CvSums> = (0..9)
        .map(|i| {
            let mut s = CvSums::default();
            for k in 0..3 {
                let a = (i * 3 + k) as f64;
                s.add(Vec3::new(10.0 * a as f32, -(a as f32), 0.0), [a, a, 0.0]);
            }
            s
        })
        .collect();
    let a = neighbour_alphas(&steep, 3, 3, 1);
    assert!(a
        .iter()
        .all(|a| a[0] == ALPHA_MAX && a[1] == 0.0 && a[2] == 1.0));
}
