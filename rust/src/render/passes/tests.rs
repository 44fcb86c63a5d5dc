//! The pass layer drives a toy method — every sample a constant plus uniform noise whose
//! amplitude differs between the image's halves — that writes no line of its own for
//! budgets, progress, stopping, adaptive counts or stats: all of it comes from
//! [`run_passes`].

use std::sync::atomic::AtomicU32;
use std::sync::Mutex;

use glam::Vec3;

use super::*;
use crate::render::estimator::{BandPixel, PixelTiming};
use crate::render::sums::{resolve, CvSums};
use crate::sampling::rng::Sampler;
use crate::sampling::sobol::PixelSampler;

const W: usize = 24;
const H: usize = 16;

/// Radiance `level`, plus noise uniform in `[-noise, noise]` on the left half of the image
/// (the right half is exact).
struct Toy {
    level: f32,
    noise: f32,
    /// Passes run, as the driver planned them.
    plans: Mutex<Vec<PassPlan>>,
    /// Notes the pilot left: samples each pixel took in it.
    pilot_notes: Option<Vec<u32>>,
    /// Spin this many iterations per sample (a cost to budget against).
    spin: u32,
    /// Shade each band sample-major ([`PixelPass::shade_band`]) instead of pixel by pixel.
    banded: bool,
    /// The bands [`PixelPass::shade_band`] was given: (first pixel, pixels).
    bands: Mutex<Vec<(usize, usize)>>,
}

impl Toy {
    fn new(noise: f32) -> Self {
        Self {
            level: 0.5,
            noise,
            plans: Mutex::default(),
            pilot_notes: None,
            spin: 0,
            banded: false,
            bands: Mutex::default(),
        }
    }
}

struct ToyPass<'a> {
    toy: &'a Toy,
}

/// Samples a band shaded.
#[derive(Default)]
struct Count(u64);

impl Merge for Count {
    fn merge(&mut self, other: Self) {
        self.0 += other.0;
    }
}

impl PixelPass for ToyPass<'_> {
    type Work = Count;
    type Note = u32;
    type Sums = CvSums;

    fn shade_pixel(
        &self,
        pixel: usize,
        samples: std::ops::Range<u32>,
        acc: &mut CvSums,
        work: &mut Count,
        note: &mut u32,
    ) -> PixelTiming {
        let noisy = pixel % W < W / 2;
        for s in samples.clone() {
            let u = PixelSampler::new(7, pixel as u64, s as u64).get(0);
            let mut x = u;
            for _ in 0..self.toy.spin {
                x = std::hint::black_box(x * 0.999 + 1e-3);
            }
            let noise = if noisy {
                self.toy.noise * (2.0 * u - 1.0)
            } else {
                0.0
            };
            acc.add(Vec3::splat(self.toy.level + noise + 0.0 * x), [0.0; 3]);
            work.0 += 1;
        }
        *note += samples.len() as u32;
        PixelTiming {
            anchor_ns: 0,
            sample_ns: 1 + samples.len() as u64,
        }
    }

    /// Banded: sample `s` of every pixel of the band that is due one, then `s + 1`; each
    /// pixel still adds its samples in order, so its sums are the pixel-by-pixel ones.
    fn shade_band(
        &self,
        pixels: &mut [BandPixel<'_, CvSums, u32>],
        work: &mut Count,
        stop: &dyn Fn() -> bool,
    ) {
        if let Some(p) = pixels.first() {
            self.toy.bands.lock().unwrap().push((p.pixel, pixels.len()));
        }
        if !self.toy.banded {
            return crate::render::estimator::shade_pixels(self, pixels, work, stop);
        }
        let lo = pixels.iter().map(|p| p.acc.n).min().unwrap_or(0);
        let hi = pixels.iter().map(|p| p.target).max().unwrap_or(0);
        for s in lo..hi {
            if stop() {
                return;
            }
            for p in pixels.iter_mut().filter(|p| p.acc.n == s && s < p.target) {
                let t = self.shade_pixel(p.pixel, s..s + 1, p.acc, work, p.note);
                p.timing.sample_ns += t.sample_ns;
            }
        }
    }
}

impl PixelEstimator for Toy {
    type Work = Count;
    type Note = u32;
    type Sums = CvSums;
    const ADAPTS: bool = true;
    type Pass<'a> = ToyPass<'a>;

    fn pass<R>(&self, plan: &PassPlan, run: impl FnOnce(&ToyPass<'_>) -> R) -> R {
        self.plans.lock().unwrap().push(*plan);
        run(&ToyPass { toy: self })
    }

    fn after_pilot(&mut self, notes: &[u32], _width: usize, _height: usize) {
        self.pilot_notes = Some(notes.to_vec());
    }

    fn shares(
        &self,
        sums: &[CvSums],
        costs: Option<&[f32]>,
        width: usize,
        height: usize,
    ) -> Option<SampleShares> {
        let plain = vec![[0.0; 3]; sums.len()];
        Some(SampleShares::measure(sums, &plain, costs, width, height))
    }
}

fn run(toy: &mut Toy, params: PassParams, threads: usize) -> PassRun<CvSums, Count> {
    run_passes(
        toy,
        W,
        H,
        &params,
        Instant::now(),
        Some(threads),
        &mut |_, _| true,
    )
    .unwrap()
}

/// Even counts: one pass, every pixel `spp` samples, the constant as the estimate, the
/// stats' counts agreeing with the sums, and the band work merged.
#[test]
fn even_counts_take_one_pass() {
    let mut toy = Toy::new(0.0);
    let params = PassParams {
        spp: 8,
        time_budget: None,
        adaptive: false,
        first_spp: None,
    };
    let run = run(&mut toy, params, 2);
    assert_eq!(run.passes, 1);
    assert!(run.complete);
    assert_eq!((run.min_spp(), run.max_spp()), (8, 8));
    assert_eq!(run.samples(), (8 * W * H) as u64);
    assert_eq!(run.total.0, run.samples());
    let (image, variance) = resolve(&run.sums, &vec![[0.0; 3]; W * H]);
    assert!(image.iter().all(|p| *p == [0.5; 3]));
    assert!(variance.iter().all(|v| *v == [0.0; 3]));
    let plans = toy.plans.lock().unwrap();
    assert_eq!(plans.len(), 1);
    assert!(!plans[0].probe && !plans[0].pilot);
}

/// Adaptive counts without a budget: a pilot of a quarter of the samples evenly, whose
/// notes reach the method, then the rest where the error is — the noisy half — at `spp`
/// on average; and bit-identical sums on one and three threads.
#[test]
fn adaptive_counts_follow_the_noise() {
    let params = PassParams {
        spp: 16,
        time_budget: None,
        adaptive: true,
        first_spp: None,
    };
    let mut toy = Toy::new(0.4);
    let one = run(&mut toy, params, 1);
    assert_eq!(one.passes, 2);
    let plans = toy.plans.lock().unwrap().clone();
    assert!(plans[0].pilot && !plans[1].pilot);
    let pilot = toy.pilot_notes.clone().expect("the pilot's notes");
    assert!(pilot.iter().all(|&n| n == 4), "a quarter of 16 evenly");
    assert!(one.samples() <= 16 * (W * H) as u64);
    assert!(one.samples() >= 15 * (W * H) as u64);
    let counts = one.counts();
    let (noisy, exact): (Vec<_>, Vec<_>) = (0..W * H).partition(|i| i % W < W / 2);
    let mean =
        |ids: &[usize]| ids.iter().map(|&i| counts[i] as f64).sum::<f64>() / ids.len() as f64;
    assert!(
        mean(&noisy) > 4.0 * mean(&exact),
        "noisy {} exact {}",
        mean(&noisy),
        mean(&exact)
    );
    assert!(one.adaptive_gain.is_some_and(|g| g > 1.0));
    let three = run(&mut Toy::new(0.4), params, 3);
    assert_eq!(one.sums, three.sums);
}

/// A time budget: a probe pass over one band in [`PassSchedule::PROBE_STRIDE`], then passes
/// sized by its timing until the budget is spent; every pixel ends with a sample and
/// at most `spp`.
#[test]
fn a_budget_starts_with_a_probe() {
    let mut toy = Toy::new(0.1);
    toy.spin = 2000;
    let params = PassParams {
        spp: 1 << 12,
        time_budget: Some(0.05),
        adaptive: false,
        first_spp: None,
    };
    let run = run(&mut toy, params, 2);
    let plans = toy.plans.lock().unwrap().clone();
    assert!(plans[0].probe);
    assert!(plans.len() >= 2 && plans[1..].iter().all(|p| !p.probe));
    assert_eq!(run.passes as usize, plans.len());
    assert!(run.min_spp() >= 1 && run.max_spp() <= 1 << 12);
}

/// A budget with `first_spp`: no probe; the first pass gives every pixel that many
/// samples however short the budget, the passes after it add to them.
#[test]
fn a_first_pass_promises_its_samples_under_any_budget() {
    let mut toy = Toy::new(0.1);
    toy.spin = 2000;
    let params = PassParams {
        spp: 1 << 12,
        time_budget: Some(1e-6),
        adaptive: false,
        first_spp: Some(6),
    };
    let run = run(&mut toy, params, 2);
    let plans = toy.plans.lock().unwrap().clone();
    assert!(plans.iter().all(|p| !p.probe));
    assert!(run.min_spp() >= 6, "{}", run.min_spp());
}

/// A `false` from progress stops the render after the pass under way, part-way: the
/// result says so, and what was shaded is kept.
#[test]
fn progress_can_stop_the_passes() {
    let mut toy = Toy::new(0.0);
    toy.spin = 20_000;
    let calls = AtomicU32::new(0);
    let params = PassParams {
        spp: 256,
        time_budget: None,
        adaptive: false,
        first_spp: None,
    };
    let run = run_passes(
        &mut toy,
        W,
        H,
        &params,
        Instant::now(),
        Some(1),
        &mut |done, planned| {
            assert_eq!(planned, 256 * (W * H) as u64);
            assert!(done <= planned);
            calls.fetch_add(1, Ordering::Relaxed);
            false
        },
    )
    .unwrap();
    assert!(calls.load(Ordering::Relaxed) >= 1);
    assert_eq!(run.passes, 1);
    assert!(!run.complete);
    assert!(run.samples() < 256 * (W * H) as u64);
    assert!(run.sums.iter().all(|s| s.n == 0 || s.n == 256));
    assert_eq!(run.total.0, run.samples());
}

/// Sums with work of their own before any sample: due until their first visit
/// ([`PixelSums::due`]).
#[derive(Clone, Default)]
struct Visited {
    visits: u32,
    n: u32,
}

impl PixelSums for Visited {
    fn samples(&self) -> u32 {
        self.n
    }

    fn due(&self, target: u32) -> bool {
        self.visits == 0 || self.n < target
    }
}

/// A method whose pixels count their visits and samples.
struct Visits;

impl PixelPass for Visits {
    type Work = ();
    type Note = ();
    type Sums = Visited;

    fn shade_pixel(
        &self,
        _pixel: usize,
        samples: std::ops::Range<u32>,
        acc: &mut Visited,
        _work: &mut (),
        _note: &mut (),
    ) -> PixelTiming {
        assert_eq!(samples.start, acc.n);
        acc.visits += 1;
        acc.n += samples.len() as u32;
        PixelTiming::default()
    }
}

impl PixelEstimator for Visits {
    type Work = ();
    type Note = ();
    type Sums = Visited;
    type Pass<'a> = Visits;

    fn pass<R>(&self, _plan: &PassPlan, run: impl FnOnce(&Visits) -> R) -> R {
        run(self)
    }
}

/// A pixel due at its target is shaded with no sample: at 0 spp one pass visits every
/// pixel once; at 3 spp, once with its samples.
#[test]
fn a_pixel_due_at_its_target_is_visited_without_samples() {
    for spp in [0, 3] {
        let params = PassParams {
            spp,
            time_budget: None,
            adaptive: false,
            first_spp: None,
        };
        let run = run_passes(
            &mut Visits,
            W,
            H,
            &params,
            Instant::now(),
            Some(2),
            &mut |_, _| true,
        )
        .unwrap();
        assert_eq!(
            (run.passes, run.samples()),
            (1, spp as u64 * (W * H) as u64)
        );
        assert!(run.sums.iter().all(|s| s.visits == 1 && s.n == spp));
    }
}

/// A method that shades a band its own way ([`PixelPass::shade_band`], here sample-major)
/// gets the sums, counts and work of pixel-by-pixel shading, bit for bit, with even and
/// adaptive counts; even counts hand it whole bands of [`BAND_ROWS`] rows.
#[test]
fn a_band_hook_changes_nothing_but_the_order() {
    for adaptive in [false, true] {
        let params = PassParams {
            spp: 16,
            time_budget: None,
            adaptive,
            first_spp: None,
        };
        let mut plain = Toy::new(0.4);
        let mut banded = Toy::new(0.4);
        banded.banded = true;
        let (a, b) = (run(&mut plain, params, 2), run(&mut banded, params, 2));
        assert_eq!(a.sums, b.sums);
        assert_eq!((a.passes, a.total.0), (b.passes, b.total.0));
        assert_eq!(a.counts(), b.counts());
        assert_eq!(plain.pilot_notes, banded.pilot_notes);
        let mut bands = banded.bands.lock().unwrap().clone();
        bands.sort();
        if !adaptive {
            assert_eq!(bands.len(), H.div_ceil(BAND_ROWS));
            for (k, (first, len)) in bands.iter().enumerate() {
                assert_eq!(*first, k * BAND_ROWS * W);
                assert_eq!(*len, BAND_ROWS.min(H - k * BAND_ROWS) * W);
            }
        }
        assert!(bands
            .iter()
            .all(|(first, len)| first % W == 0 && len % W == 0));
    }
}
