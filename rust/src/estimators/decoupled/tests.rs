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

/// A pass after the first that the budget's deadline ends (part-way, or as it finishes) is
/// dropped whole: whatever the timing, a budgeted run keeps whole passes of every pixel and
/// its samples equal a run asked for as many. Budgets of 1.5, 2.5 and 3.5 times a pass put
/// the deadline inside a pass. (Progress reports that counted samples beyond those kept
/// show a pass the deadline ended part-way; they come every 0.1 s, so only passes longer
/// than that show, and the count is printed, not asserted.)
#[test]
fn converge_visibility_drops_the_pass_its_deadline_ends() {
    use super::{Relighter, VisibilitySource, VISIBILITY_PASS_SPP};
    use crate::camera::GBuffer;
    use crate::estimators::direct::ProductLevel;
    let setup = crate::scenes::load("garage", 0.25, 0).unwrap();
    let camera = setup.camera.with_resolution(64, 48).unwrap();
    let (scene, env) = (&setup.scene, &setup.envmap);
    let gbuffer = GBuffer::render(scene, &camera, 0, false, Some(2)).unwrap();
    let pixels = gbuffer.len() as u64;
    let level = ProductLevel::PerMaterial;
    let converge = |spp: u32, budget: Option<f64>, most: &mut u64| {
        let mut rl = Relighter::new(scene, gbuffer.clone(), VisibilitySource::Pixels).unwrap();
        let mut progress = |done: u64, _: u64| {
            *most = (*most).max(done);
            true
        };
        let (taken, _) = rl
            .converge_visibility(scene, env, spp, 7, level, Some(2), budget, &mut progress)
            .unwrap();
        (taken, rl.converged.unwrap())
    };
    let start = std::time::Instant::now();
    converge(VISIBILITY_PASS_SPP, None, &mut 0);
    let pass = start.elapsed().as_secs_f64();
    let mut dropped = 0;
    for k in [1.5, 2.5, 3.5] {
        let mut most = 0;
        let (taken, budgeted) = converge(1024, Some(k * pass), &mut most);
        assert!(
            taken >= VISIBILITY_PASS_SPP && taken % VISIBILITY_PASS_SPP == 0,
            "{taken}"
        );
        dropped += (most > taken as u64 * pixels) as u32;
        let (_, asked) = converge(taken, None, &mut 0);
        assert_eq!(budgeted.spp, taken);
        for (a, b) in asked.stats.iter().zip(&budgeted.stats) {
            assert_eq!((a.samples, a.visible), (b.samples, b.visible), "{k} passes");
        }
        let n = asked.stats.len();
        for i in 0..n {
            let (a, b) = (i * asked.words, i * budgeted.words);
            assert_eq!(
                asked.bits[a..a + asked.words],
                budgeted.bits[b..b + asked.words]
            );
        }
    }
    eprintln!("passes of {pass:.3} s: {dropped} of 3 budgets seen to end one part-way");
}
