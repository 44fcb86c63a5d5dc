use super::*;
use crate::sampling::rng::{hash4, to_unit_f64};

/// `(V_P, V_P')` of the four ray types of Table 1.
const TYPES: [(bool, bool); 4] = [(false, false), (false, true), (true, false), (true, true)];

fn u(seed: u64, i: u64, d: u64) -> f64 {
    to_unit_f64(hash4(seed, i, 0, d))
}

/// Random shares of the four types (some exactly 0 now and then).
fn random_fractions(seed: u64, k: u64) -> Fractions {
    let mut f = [0.0; 4];
    for (i, x) in f.iter_mut().enumerate() {
        let v = u(seed, k, i as u64);
        *x = if v < 0.15 { 0.0 } else { v };
    }
    if f.iter().sum::<f64>() == 0.0 {
        f[3] = 1.0;
    }
    let n: f64 = f.iter().sum();
    Fractions {
        f: f.map(|x| x / n),
    }
}

/// The shares a proxy of `kind` can give: no type 2 outside, no type 3 inside.
fn restrict(fr: Fractions, kind: ProxyKind) -> Fractions {
    let mut f = fr.f;
    match kind {
        ProxyKind::Outside => f[1] = 0.0,
        ProxyKind::Inside => f[2] = 0.0,
        ProxyKind::General => {}
    }
    let n: f64 = f.iter().sum();
    if n == 0.0 {
        return Fractions {
            f: [0.0, 0.0, 0.0, 1.0],
        };
    }
    Fractions {
        f: f.map(|x| x / n),
    }
}

/// The exact expectation of eq. 8 for one ray: `Σ_t p_t value_t`.
fn expectation(p: &Probabilities, scene: bool, proxy: bool) -> f64 {
    Term::ALL
        .into_iter()
        .filter(|&t| p.of(t) > 0.0)
        .map(|t| {
            // A `u` inside term t's interval.
            let lo: f64 = Term::ALL
                .iter()
                .take_while(|&&s| s != t)
                .map(|&s| p.of(s))
                .sum();
            let (value, _) = estimate(p, lo + 0.5 * p.of(t), proxy, || scene);
            p.of(t) * value
        })
        .sum()
}

/// Table 2, row by row, and eq. 7: every term's value for every ray type, and their
/// expectation is `V_P` for any probabilities that keep every term.
#[test]
fn every_ray_type_gives_table_2_and_its_expectation_is_the_visibility() {
    let p = Probabilities::new(0.5, 0.3, 0.2).unwrap();
    let want = [
        // (a), (b), (c) for types 1..4
        [0.0, 0.0, 0.0],
        [1.0 / 0.5, 0.0, -1.0 / 0.2],
        [0.0, 1.0 / 0.3, 0.0],
        [1.0 / 0.5, 0.0, 0.0],
    ];
    let mid = [0.25, 0.65, 0.9];
    for ((scene, proxy), row) in TYPES.into_iter().zip(want) {
        for (k, t) in Term::ALL.into_iter().enumerate() {
            assert_eq!(p.choose(mid[k]), t);
            let mut traced = false;
            let (v, said) = estimate(&p, mid[k], proxy, || {
                traced = true;
                scene
            });
            assert_eq!(v, row[k], "type ({scene}, {proxy}) term {t:?}");
            // The scene is traced exactly where the term needs it.
            let needs = match t {
                Term::Proxy => false,
                Term::Over => !proxy,
                Term::Under => proxy,
            };
            assert_eq!((traced, said), (needs, needs));
        }
    }
    for k in 0..200 {
        let (a, b) = (u(3, k, 0), u(3, k, 1));
        let p = Probabilities::new(a.min(b), (a - b).abs(), 1.0 - a.max(b)).unwrap();
        if p.p.iter().any(|&x| x <= 0.0) {
            continue;
        }
        for (scene, proxy) in TYPES {
            let e = expectation(&p, scene, proxy);
            assert!(
                (e - scene as u8 as f64).abs() < 1e-12,
                "{p:?} {scene} {proxy}: {e}"
            );
        }
    }
}

/// Outside proxies with p3 = 0 and inside ones with p2 = 0 stay unbiased on the rays
/// their guarantee allows (eq. 17, 19).
#[test]
fn the_special_cases_drop_a_term_without_bias() {
    let outside = Probabilities::new(0.7, 0.3, 0.0).unwrap();
    let inside = Probabilities::new(0.6, 0.0, 0.4).unwrap();
    for (scene, proxy) in TYPES {
        let v = scene as u8 as f64;
        // Outside proxies meet no type 2 (hit P, miss P'), inside ones no type 3.
        if scene || !proxy {
            assert_eq!(expectation(&outside, scene, proxy), v);
        }
        if !scene || proxy {
            assert_eq!(expectation(&inside, scene, proxy), v);
        }
    }
    assert_eq!(Probabilities::equal(ProxyKind::Outside).p, [0.5, 0.5, 0.0]);
    assert_eq!(Probabilities::equal(ProxyKind::Inside).p, [0.5, 0.0, 0.5]);
    assert_eq!(Probabilities::equal(ProxyKind::General).p, [1.0 / 3.0; 3]);
    // A zero term is never drawn, whatever u.
    for k in 0..1000 {
        let x = u(5, k, 0);
        assert_ne!(outside.choose(x), Term::Under);
        assert_ne!(inside.choose(x), Term::Over);
    }
    assert_eq!(outside.choose(0.999_999_999), Term::Over);
    assert_eq!(inside.choose(0.999_999_999), Term::Under);
}

/// Eq. 8's mean and eq. 14/16's variance on synthetic populations of rays with known
/// shares: within 4 standard errors of the sample mean and of the sample second moment.
#[test]
fn the_sample_mean_and_variance_match_eq_8_and_eq_14() {
    const N: u64 = 200_000;
    for (k, kind) in [
        ProxyKind::General,
        ProxyKind::Outside,
        ProxyKind::Inside,
        ProxyKind::General,
    ]
    .into_iter()
    .enumerate()
    {
        let fr = restrict(random_fractions(11, k as u64), kind);
        for p in [
            Probabilities::equal(kind),
            Probabilities::least_variance(&fr, kind, 0.05),
        ] {
            let cdf: Vec<f64> =
                fr.f.iter()
                    .scan(0.0, |acc, &x| {
                        *acc += x;
                        Some(*acc)
                    })
                    .collect();
            let (mut s1, mut s2, mut s4) = (0.0, 0.0, 0.0);
            for i in 0..N {
                let ty = cdf.partition_point(|&c| c <= u(17, i, 0)).min(3);
                let (scene, proxy) = TYPES[ty];
                let (x, _) = estimate(&p, u(17, i, 1), proxy, || scene);
                s1 += x;
                s2 += x * x;
                s4 += x * x * x * x;
            }
            let n = N as f64;
            let (mean, m2, m4) = (s1 / n, s2 / n, s4 / n);
            let var = m2 - mean * mean;
            let se_mean = (var / n).sqrt();
            assert!(
                (mean - fr.v_avg()).abs() <= 4.0 * se_mean,
                "{kind:?} {p:?}: mean {mean} against V_avg {}",
                fr.v_avg()
            );
            // E[X²] = Var + V_avg² (eq. 13), estimated with the SE of X².
            let want_m2 = p.variance(&fr) + fr.v_avg() * fr.v_avg();
            let se_m2 = ((m4 - m2 * m2) / n).sqrt();
            assert!(
                (m2 - want_m2).abs() <= 4.0 * se_m2 + 1e-12,
                "{kind:?} {p:?}: E[X²] {m2} against {want_m2}"
            );
        }
    }
}

/// Eq. 16 (summary figures) agrees with eq. 14 (shares), and eq. 18 and 20 with both
/// for their proxies.
#[test]
fn eq_16_18_and_20_agree_with_eq_14() {
    for k in 0..300 {
        let (v, fh, fm) = (u(23, k, 0), u(23, k, 1), u(23, k, 2));
        let fr = Fractions::new(v, fh, fm).unwrap();
        assert!((fr.v_avg() - v).abs() < 1e-12);
        assert!((fr.f_hit() - fh).abs() < 1e-9 && (fr.f_miss() - fm).abs() < 1e-9);
        let (a, b) = (0.05 + 0.9 * u(23, k, 3), 0.05 + 0.9 * u(23, k, 4));
        let p = Probabilities::new(a * b, a * (1.0 - b), 1.0 - a).unwrap();
        let [p1, p2, p3] = p.p;
        let eq16 =
            (1.0 - v) * (1.0 - fh) * (p1 + p3) / (p1 * p3) + v * (1.0 - fm) / p2 + v * fm / p1
                - v * v;
        assert!((p.variance(&fr) - eq16).abs() < 1e-9 * eq16.abs().max(1.0));
        // Outside: f_hit = 1, p3 = 0 (eq. 18).
        let out = Fractions::new(v, 1.0, fm).unwrap();
        let po = Probabilities::new(p1, 1.0 - p1, 0.0).unwrap();
        let eq18 = v * (1.0 - fm) / (1.0 - p1) + v * fm / p1 - v * v;
        assert!((po.variance(&out) - eq18).abs() < 1e-9 * eq18.abs().max(1.0));
        // Inside: f_miss = 1, p2 = 0 (eq. 20).
        let ins = Fractions::new(v, fh, 1.0).unwrap();
        let pi = Probabilities::new(p1, 0.0, 1.0 - p1).unwrap();
        let eq20 = (1.0 - v) * (1.0 - fh) / (p1 * (1.0 - p1)) + v / p1 - v * v;
        assert!((pi.variance(&ins) - eq20).abs() < 1e-9 * eq20.abs().max(1.0));
    }
}

/// The least-variance probabilities against a brute-force search of the simplex (step
/// 1/400), and against §4.1's closed forms for outside and inside proxies.
#[test]
fn the_least_variance_probabilities_beat_a_search_of_the_simplex() {
    for k in 0..40 {
        let kind = ProxyKind::ALL[k as usize % 3];
        let fr = restrict(random_fractions(29, k), kind);
        let best = Probabilities::least_variance(&fr, kind, 0.0);
        let v = best.variance(&fr);
        const STEPS: usize = 400;
        for i in 0..=STEPS {
            for j in 0..=STEPS - i {
                let (p2, p3) = (i as f64 / STEPS as f64, j as f64 / STEPS as f64);
                let Ok(p) = Probabilities::new((1.0 - p2 - p3).max(0.0), p2, p3) else {
                    continue;
                };
                assert!(v <= p.variance(&fr) + 1e-12, "{kind:?} {fr:?}: {best:?}");
            }
        }
    }
    // §4.1, outside: p1 = (f_miss − √(f_miss − f_miss²)) / (2 f_miss − 1).
    for fm in [0.01, 0.2, 0.49, 0.51, 0.8, 0.99] {
        let fr = Fractions::new(0.6, 1.0, fm).unwrap();
        let p = Probabilities::least_variance(&fr, ProxyKind::Outside, 0.0);
        let paper = (fm - (fm - fm * fm).sqrt()) / (2.0 * fm - 1.0);
        assert!(
            (p.p[0] - paper).abs() < 1e-12 && p.p[2] == 0.0,
            "{fm}: {p:?}"
        );
    }
    // Its 0/0 at f_miss = 1/2 is p1 = 1/2 here.
    let half = Fractions::new(0.6, 1.0, 0.5).unwrap();
    let p = Probabilities::least_variance(&half, ProxyKind::Outside, 0.0);
    assert!((p.p[0] - 0.5).abs() < 1e-12);
    // §4.1, inside (its fraction read with the square root over the whole numerator):
    // p1 = (1 − f_hit (1 − V) − √((1 − f_hit)(1 − V)(1 − f_hit (1 − V)))) / V.
    for (v, fh) in [(0.3, 0.2), (0.7, 0.9), (0.5, 0.5), (0.95, 0.05)] {
        let fr = Fractions::new(v, fh, 1.0).unwrap();
        let p = Probabilities::least_variance(&fr, ProxyKind::Inside, 0.0);
        let s = 1.0 - fh * (1.0 - v);
        let paper = (s - ((1.0 - fh) * (1.0 - v) * s).sqrt()) / v;
        assert!(
            (p.p[0] - paper).abs() < 1e-12 && p.p[1] == 0.0,
            "{v} {fh}: {p:?}"
        );
    }
}

/// The extremes: f_hit = 1 and f_miss = 1 (a perfect proxy: the proxy alone), V_avg 0
/// and 1, every ray of one type; no NaN anywhere and the floor keeps every needed term.
#[test]
fn extreme_shares_give_finite_probabilities_that_keep_the_needed_terms() {
    let cases = [
        (0.0, 1.0, 1.0),
        (1.0, 1.0, 1.0),
        (0.0, 0.0, 1.0),
        (1.0, 1.0, 0.0),
        (0.5, 1.0, 1.0),
        (0.5, 0.0, 0.0),
    ];
    for (v, fh, fm) in cases {
        let fr = Fractions::new(v, fh, fm).unwrap();
        for kind in ProxyKind::ALL {
            for floor in [0.0, 0.02] {
                let p = Probabilities::least_variance(&fr, kind, floor);
                assert!(p.p.iter().all(|x| x.is_finite() && *x >= 0.0), "{p:?}");
                assert!((p.p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
                if floor > 0.0 {
                    p.check_unbiased(kind).unwrap();
                }
                // Finite wherever the shares keep the kind's guarantee (no type 2
                // outside, no type 3 inside).
                let kept = match kind {
                    ProxyKind::Outside => fr.f[1] == 0.0,
                    ProxyKind::Inside => fr.f[2] == 0.0,
                    ProxyKind::General => true,
                };
                assert!(p.variance(&fr).is_finite() || floor == 0.0 || !kept);
            }
        }
    }
    // A perfect proxy (f_hit = f_miss = 1): the proxy alone ...
    let perfect = Fractions::new(0.4, 1.0, 1.0).unwrap();
    let p = Probabilities::least_variance(&perfect, ProxyKind::General, 0.0);
    assert_eq!(p.p, [1.0, 0.0, 0.0]);
    // ... whose variance is exact visibility's over the point's rays, V (1 − V).
    assert!((p.variance(&perfect) - 0.4 * 0.6).abs() < 1e-12);
    // Probabilities 0 and 1 are valid values, but biased where a needed term is 0.
    let only_proxy = Probabilities::new(1.0, 0.0, 0.0).unwrap();
    for kind in ProxyKind::ALL {
        assert!(only_proxy.check_unbiased(kind).is_err());
    }
    Probabilities::new(0.0, 1.0, 0.0)
        .unwrap()
        .check_unbiased(ProxyKind::Outside)
        .unwrap_err();
}

/// Bad probabilities and shares are errors naming the argument.
#[test]
fn bad_probabilities_and_shares_name_their_argument() {
    let name = |e: Error| match e {
        Error::InvalidArgument { name, .. } => name,
        other => panic!("{other:?}"),
    };
    for (a, b, c) in [
        (-0.1, 0.6, 0.5),
        (f64::NAN, 0.5, 0.5),
        (0.5, 0.5, 0.5),
        (0.2, 0.2, 0.2),
        (f64::INFINITY, 0.0, 0.0),
    ] {
        assert_eq!(
            name(Probabilities::new(a, b, c).unwrap_err()),
            "probabilities"
        );
    }
    assert_eq!(
        name(
            Probabilities::new(0.5, 0.5, 0.0)
                .unwrap()
                .check_unbiased(ProxyKind::General)
                .unwrap_err()
        ),
        "probabilities"
    );
    assert_eq!(name(Fractions::new(1.5, 0.5, 0.5).unwrap_err()), "v_avg");
    assert_eq!(
        name(Fractions::new(0.5, f64::NAN, 0.5).unwrap_err()),
        "f_hit"
    );
    assert_eq!(name(Fractions::new(0.5, 0.5, -0.1).unwrap_err()), "f_miss");
}

/// Probe counts with a prior: no share is 0, so no needed term is dropped; without rays
/// or prior, nothing.
#[test]
fn probe_counts_with_a_prior_keep_every_share_positive() {
    let fr = Fractions::from_counts([10, 0, 0, 6], 0.5).unwrap();
    assert!(fr.f.iter().all(|&x| x > 0.0));
    assert!((fr.f.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    assert!((fr.f[0] - 10.5 / 18.0).abs() < 1e-12);
    let p = Probabilities::least_variance(&fr, ProxyKind::General, 0.0);
    p.check_unbiased(ProxyKind::General).unwrap();
    assert!(Fractions::from_counts([0; 4], 0.0).is_none());
    assert_eq!(
        Fractions::from_counts([0, 0, 0, 4], 0.0).unwrap().f,
        [0.0, 0.0, 0.0, 1.0]
    );
}

/// Eq. 22–24 and the least work: the heuristic moves probability to the proxy where
/// proxy and scene agree; the numeric minimum of variance × cost is at most that of the
/// least-variance and the heuristic probabilities, and within 1% of a fine search.
#[test]
fn the_least_work_beats_the_cost_heuristic_and_a_search() {
    // An umbra: almost every ray of type 1 (both block).
    let umbra = Fractions {
        f: [0.97, 0.01, 0.01, 0.01],
    };
    let kind = ProxyKind::General;
    let lv = Probabilities::least_variance(&umbra, kind, 0.01);
    let heur = lv.cost_heuristic(&umbra, kind, 0.01);
    assert!(heur.p[0] > lv.p[0]);
    let s = (1.0f64 - 0.98).powf(0.25);
    assert!((heur.p[1] - lv.p[1] * s).abs() < 1e-12);
    // Perfect agreement: p2 = p3 = 0 before the floor.
    let agree = Fractions {
        f: [0.5, 0.0, 0.0, 0.5],
    };
    let h = Probabilities::equal(kind).cost_heuristic(&agree, kind, 0.0);
    assert_eq!(h.p, [1.0, 0.0, 0.0]);

    let (c_proxy, c_scene) = (1.0, 20.0);
    for k in 0..12 {
        let fr = random_fractions(31, k);
        let work = |p: &Probabilities| p.variance(&fr).max(0.0) * p.cost(&fr, c_proxy, c_scene);
        let best = Probabilities::least_work(&fr, kind, 0.01, c_proxy, c_scene);
        best.check_unbiased(kind).unwrap();
        let lv = Probabilities::least_variance(&fr, kind, 0.01);
        let heur = lv.cost_heuristic(&fr, kind, 0.01);
        assert!(work(&best) <= work(&lv) * (1.0 + 1e-9), "{fr:?}");
        assert!(work(&best) <= work(&heur) * (1.0 + 1e-9), "{fr:?}");
        const STEPS: usize = 300;
        let mut search = f64::INFINITY;
        for i in 0..=STEPS {
            for j in 0..=STEPS - i {
                let (p2, p3) = (i as f64 / STEPS as f64, j as f64 / STEPS as f64);
                let p = Probabilities {
                    p: [1.0 - p2 - p3, p2, p3],
                };
                if p.p.iter().all(|&x| x >= 0.01) {
                    search = search.min(work(&p));
                }
            }
        }
        assert!(
            work(&best) <= search * 1.01,
            "{fr:?}: {} vs {search}",
            work(&best)
        );
    }
}
