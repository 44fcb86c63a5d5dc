use super::blend::variance_upper_factor;

#[test]
fn the_variance_bound_follows_the_chi_square_quantiles() {
    // k / χ²₀.₀₅(k) from tables of the quantile: 1, 10, 15, 30 and 100 degrees of
    // freedom; no bound below two values.
    for (count, exact) in [
        (2u64, 1.0 / 0.003_932),
        (11, 10.0 / 3.940),
        (16, 15.0 / 7.261),
        (31, 30.0 / 18.493),
        (101, 100.0 / 77.929),
    ] {
        let f = variance_upper_factor(count);
        assert!(
            (f / exact - 1.0).abs() < 0.01,
            "{count}: {f} against {exact}"
        );
    }
    assert_eq!(variance_upper_factor(1), 1.0);
    assert_eq!(variance_upper_factor(0), 1.0);
    assert!(variance_upper_factor(1 << 40) > 1.0);
}
