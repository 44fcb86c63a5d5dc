//! The distribution matrix against its definitions: α-max and balance weights partition
//! every light, draws follow `p̄` (chi-square), eq. 6.2 is unbiased for the exact sum with
//! rows that miss lights or are empty, and bad confidences are named.

use super::*;
use crate::sampling::rng::{hash4, to_unit_f64};

fn unit(seed: u64, k: u64) -> f64 {
    to_unit_f64(hash4(seed, k, 0, 17))
}

/// Running sums of `w`.
fn cdf(w: &[f64]) -> Vec<f64> {
    let mut t = 0.0;
    w.iter()
        .map(|x| {
            t += x;
            t
        })
        .collect()
}

/// Weights over `n` lights: random, zero for about `zeros` of them (a fraction).
fn weights(seed: u64, n: usize, zeros: f64) -> Vec<f64> {
    (0..n as u64)
        .map(|k| {
            if unit(seed, 2 * k) < zeros {
                0.0
            } else {
                unit(seed, 2 * k + 1).powi(3)
            }
        })
        .collect()
}

/// Records' CDFs for rows F, U, B: `records` each, some all zero (every light occluded at
/// the record), some missing many lights.
fn rows(seed: u64, n: usize, records: usize) -> Vec<(Row, Vec<f64>)> {
    let mut out = Vec::new();
    for r in 0..records as u64 {
        for (i, row) in [Row::F, Row::U, Row::B].into_iter().enumerate() {
            let s = hash4(seed, r, i as u64, 1);
            let zeros = [0.6, 0.3, 0.0][i];
            let w = if s.is_multiple_of(5) && row == Row::F {
                vec![0.0; n]
            } else {
                weights(s, n, zeros)
            };
            out.push((row, cdf(&w)));
        }
    }
    out
}

fn matrix<'a>(n: usize, rows: &'a [(Row, Vec<f64>)]) -> Matrix<'a> {
    let mut m = Matrix::new(n).unwrap();
    for (row, c) in rows {
        m.push(*row, c);
    }
    m
}

const ALPHAS: [[f64; ROWS]; 4] = [
    [1.0; ROWS],
    [0.5, 0.5, 0.5, 0.5],
    [1.0, 0.3, 0.1, 0.05],
    [0.01, 1.0, 0.2, 1.0],
];

/// Every light's weights over the rows sum to 1 under α-max (exactly one owner, with
/// `p̄ > 0`) and under balance, for random matrices and confidences, with empty rows too.
#[test]
fn weights_partition_every_light() {
    for case in 0..40u64 {
        let n = 1 + (hash4(case, 0, 0, 3) % 60) as usize;
        let records = (hash4(case, 0, 0, 4) % 4) as usize;
        let rows = rows(case, n, records);
        let m = matrix(n, &rows);
        for k in 0..n {
            for alpha in ALPHAS {
                let c = Combine::AlphaMax(alpha);
                let w = Row::ALL.map(|s| m.weight(&c, s, k));
                assert_eq!(w.iter().sum::<f64>(), 1.0, "case {case} light {k}: {w:?}");
                for s in Row::ALL {
                    assert!(w[s as usize] == 0.0 || m.pmf(s, k) > 0.0);
                }
            }
            let w: f64 = Row::ALL
                .map(|s| m.weight(&Combine::Balance, s, k))
                .iter()
                .sum();
            assert!((w - 1.0).abs() < 1e-12, "{w}");
        }
        for s in Row::ALL {
            let total: f64 = (0..n).map(|k| m.pmf(s, k)).sum();
            let served = m.records(s) > 0;
            assert!(!served || (total - 1.0).abs() < 1e-9, "{s:?} {total}");
            assert!(served || total == 0.0);
        }
    }
}

/// α-max by hand: a light goes to the first row whose `p̄` is at least `α_i p̄_i` of every
/// later row (ties to the earlier row); with no record at all, C owns everything.
#[test]
fn alpha_max_gives_each_light_to_the_first_confident_row() {
    // p̄ per light: F (0.5, 0.2, 0.3, 0), U (0.1, 0.3, 0.3, 0.3), B none, C 0.25.
    let f = cdf(&[0.5, 0.2, 0.3, 0.0]);
    let u = cdf(&[0.1, 0.3, 0.3, 0.3]);
    let mut m = Matrix::new(4).unwrap();
    m.push(Row::F, &f);
    m.push(Row::U, &u);
    let owner = |m: &Matrix<'_>, alpha, k| {
        Row::ALL
            .into_iter()
            .find(|&s| m.weight(&Combine::AlphaMax(alpha), s, k) == 1.0)
            .unwrap()
    };
    let full = [1.0; ROWS];
    assert_eq!(owner(&m, full, 0), Row::F);
    // 0.2 < 0.3 = α_U p̄_U: U's, as 0.3 >= α_C 0.25.
    assert_eq!(owner(&m, full, 1), Row::U);
    // Less trust in U alone leaves F below C's 0.25; in U and C, F's 0.2 wins.
    assert_eq!(owner(&m, [1.0, 0.5, 1.0, 1.0], 1), Row::U);
    assert_eq!(owner(&m, [1.0, 0.5, 1.0, 0.5], 1), Row::F);
    assert_eq!(owner(&m, full, 2), Row::F);
    // F holds nothing of light 3: U's 0.3 against C's 0.25.
    assert_eq!(owner(&m, full, 3), Row::U);
    let only_c = Matrix::new(4).unwrap();
    for k in 0..4 {
        assert_eq!(owner(&only_c, full, k), Row::C);
    }
}

/// 400k draws of each row of one matrix against `p̄` by Pearson's chi-square: below mean
/// plus 5 standard deviations of the statistic (fixed seed).
#[test]
fn draws_follow_the_row_average() {
    let n = 24;
    let rows = rows(9, n, 3);
    let m = matrix(n, &rows);
    for s in Row::ALL {
        if m.records(s) == 0 {
            continue;
        }
        let draws = 400_000u64;
        let mut count = vec![0u64; n];
        for j in 0..draws {
            let k = m
                .draw(s, unit(s as u64, 2 * j), unit(s as u64, 2 * j + 1))
                .unwrap();
            assert!(m.pmf(s, k) > 0.0, "{s:?} drew {k} of zero mass");
            count[k] += 1;
        }
        let (mut chi2, mut bins) = (0.0, 0);
        for (k, &c) in count.iter().enumerate() {
            let e = m.pmf(s, k) * draws as f64;
            if e > 0.0 {
                chi2 += (c as f64 - e).powi(2) / e;
                bins += 1;
            }
        }
        let dof = (bins - 1) as f64;
        assert!(
            chi2 < dof + 5.0 * (2.0 * dof).sqrt(),
            "{s:?}: {chi2} on {dof}"
        );
    }
}

/// Eq. 6.2 against the exact sum `Σ f`: 4000 independent estimates of 4 draws per row
/// within 4 standard errors, under α-max (four confidences) and balance, with records
/// whose rows miss lights that `f` lights (bad records cost variance, never bias) and
/// with no record at all (C alone). `Only(F)` misses those lights: the same test sees
/// its bias.
#[test]
fn the_estimate_is_unbiased_for_the_exact_sum() {
    let n = 50;
    let f: Vec<f64> = weights(77, n, 0.2);
    let exact: f64 = f.iter().sum();
    let shuffled = rows(5, n, 3);
    let none: Vec<(Row, Vec<f64>)> = Vec::new();
    let mut combines: Vec<Combine> = ALPHAS.iter().map(|a| Combine::AlphaMax(*a)).collect();
    combines.push(Combine::Balance);
    for (case, rows) in [&shuffled, &none].into_iter().enumerate() {
        let m = matrix(n, rows);
        for c in &combines {
            let trials = 4000u64;
            let (mut sum, mut sum2) = (0.0, 0.0);
            for t in 0..trials {
                let (x, _) = m.estimate(c, 4, (3, case as u64, t), |k| DVec3::splat(f[k]));
                sum += x.x;
                sum2 += x.x * x.x;
            }
            let mean = sum / trials as f64;
            let var = (sum2 / trials as f64 - mean * mean) / (trials - 1) as f64;
            let se = var.sqrt();
            assert!(
                se > 0.0 && (mean - exact).abs() < 4.0 * se,
                "{c:?} case {case}: {mean} vs {exact} (SE {se})"
            );
        }
    }
    // F alone misses the lights no record's F holds: biased low by their share.
    let m = matrix(n, &shuffled);
    let missed: f64 = (0..n)
        .filter(|&k| m.pmf(Row::F, k) == 0.0)
        .map(|k| f[k])
        .sum();
    assert!(missed > 0.05 * exact, "{missed} of {exact}");
    let trials = 4000u64;
    let (mut sum, mut sum2) = (0.0, 0.0);
    for t in 0..trials {
        let (x, _) = m.estimate(&Combine::Only(Row::F), 4, (3, 9, t), |k| DVec3::splat(f[k]));
        sum += x.x;
        sum2 += x.x * x.x;
    }
    let mean = sum / trials as f64;
    let se = ((sum2 / trials as f64 - mean * mean) / (trials - 1) as f64).sqrt();
    let lit = exact - missed;
    assert!((mean - lit).abs() < 4.0 * se, "{mean} vs {lit} (SE {se})");
    assert!(
        (mean - exact).abs() > 4.0 * se,
        "{mean} vs {exact} (SE {se})"
    );
}

/// Under α-max a draw its row does not own costs no call of `f` (no shadow ray); with
/// `F ∝ f` and every other row distrusted (α small) F owns every lit light and the
/// estimate is exact.
#[test]
fn unowned_draws_trace_nothing_and_a_trusted_exact_row_is_exact() {
    let n = 30;
    let f = weights(31, n, 0.3);
    let fc = cdf(&f);
    let uc = cdf(&vec![1.0; n]);
    let mut m = Matrix::new(n).unwrap();
    m.push(Row::F, &fc);
    m.push(Row::U, &uc);
    let c = Combine::AlphaMax([1.0, 1e-9, 1e-9, 1e-9]);
    let exact: f64 = f.iter().sum();
    for t in 0..50 {
        let (x, calls) = m.estimate(&c, 4, (1, 2, t), |k| DVec3::splat(f[k]));
        // F's 4 draws count, U's only of unlit lights (F holds none of them, U owns
        // them), C's never: every light has an earlier owner.
        assert!((4..=8).contains(&calls), "{calls}");
        assert!((x.x - exact).abs() < 1e-9 * exact, "{} vs {exact}", x.x);
    }
}

#[test]
fn bad_input_is_named() {
    for a in [0.0, -0.1, 1.5, f64::NAN] {
        let c = Combine::AlphaMax([1.0, a, 1.0, 1.0]);
        match c.validate() {
            Err(Error::InvalidArgument { name, .. }) => assert_eq!(name, "alpha"),
            other => panic!("{other:?}"),
        }
    }
    assert!(Combine::AlphaMax([1.0, 0.5, 1e-6, 1.0]).validate().is_ok());
    match Matrix::<f64>::new(0) {
        Err(Error::InvalidArgument { name, .. }) => assert_eq!(name, "lights"),
        other => panic!("{:?}", other.map(|m| m.lights())),
    }
}
