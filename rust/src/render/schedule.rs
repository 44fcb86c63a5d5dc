//! How many samples each pass of a budgeted render takes.

use super::MAX_SPP;

/// What one pass did, for [`PassSchedule`]: CPU nanoseconds of its pixels' set-up
/// (anchors), of its samples, and of work later passes do not repeat.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct PassWork {
    pub(crate) anchored_pixels: u64,
    pub(crate) samples: u64,
    pub(crate) anchor_ns: u64,
    pub(crate) sample_ns: u64,
    pub(crate) once_ns: u64,
}

impl std::ops::AddAssign for PassWork {
    fn add_assign(&mut self, o: Self) {
        self.anchored_pixels += o.anchored_pixels;
        self.samples += o.samples;
        self.anchor_ns += o.anchor_ns;
        self.sample_ns += o.sample_ns;
        self.once_ns += o.once_ns;
    }
}

/// Sizes the passes of a budgeted render. The first pass is a probe: [`Self::PROBE_SPP`]
/// samples in the pixels of every [`Self::PROBE_STRIDE`]-th band. From it (and any later
/// pass) the cost of a pass is modelled as wall-clock seconds per anchored pixel plus
/// seconds per sample (the CPU time of the two, scaled to the wall clock the passes took);
/// a further pass runs when one more sample per pixel fits [`Self::SHARE`] of the budget
/// left. A pass recomputes its pixels' anchors, so few passes waste least: usually the
/// probe and one main pass.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct PassSchedule {
    passes: u32,
    wall: f64,
    work: PassWork,
}

impl PassSchedule {
    /// The probe pass covers one band in this many, with this many samples per pixel (the
    /// first sample after an anchor costs half as much again as the later ones: a probe
    /// of one sample would overestimate them).
    pub(super) const PROBE_STRIDE: usize = 8;
    pub(super) const PROBE_SPP: u32 = 4;
    /// Most of the budget left that the probe spends: its bands start only until then
    /// (bands under way finish).
    pub(super) const PROBE_SHARE: f64 = 0.1;
    /// Share of the budget left that a pass aims to spend (the rest absorbs the model's
    /// error).
    const SHARE: f64 = 0.95;

    /// Wall-clock seconds per CPU nanosecond the passes so far took (the threads' share).
    pub(crate) fn wall_per_cpu_ns(&self) -> f64 {
        let w = &self.work;
        self.wall / (w.anchor_ns + w.sample_ns + w.once_ns).max(1) as f64
    }

    /// Wall-clock seconds of one pixel's anchor.
    pub(crate) fn anchor_seconds(&self) -> f64 {
        let w = &self.work;
        self.wall_per_cpu_ns() * w.anchor_ns as f64 / w.anchored_pixels.max(1) as f64
    }

    /// CPU nanoseconds of a sample, on average over the passes so far.
    pub(crate) fn sample_ns_mean(&self) -> f64 {
        self.work.sample_ns as f64 / self.work.samples.max(1) as f64
    }

    /// What a pass may spend of `left` seconds.
    pub(crate) fn spend(&self, left: f64) -> f64 {
        left * Self::SHARE
    }

    pub(crate) fn record(&mut self, wall: f64, pass: PassWork) {
        self.passes += 1;
        self.wall += wall;
        self.work += pass;
    }

    /// The sample count per pixel the next pass should bring every one of `pixels` pixels
    /// to, with `left` seconds of budget, `taken` samples already taken and every pixel
    /// at `min` or more; `None` when not even one more sample per pixel fits.
    pub(crate) fn next_target(&self, left: f64, pixels: u64, taken: u64, min: u32) -> Option<u32> {
        let w = &self.work;
        // No sample measured yet (a probe whose deadline passed before any band began):
        // nothing says what a sample costs, and a cost of zero would plan MAX_SPP.
        if w.samples == 0 || w.sample_ns == 0 {
            return None;
        }
        let per_pixel = self.anchor_seconds();
        let per_sample = self.wall_per_cpu_ns() * w.sample_ns as f64 / w.samples.max(1) as f64;
        let spend = self.spend(left) - per_pixel * pixels as f64;
        // Samples that fit, on top of those taken, spread over every pixel: a pass is worth
        // its anchors when it adds a sample per pixel on average (or gives every pixel a
        // first one).
        let total = taken as f64 + spend / per_sample.max(1e-12);
        let target = (total / pixels.max(1) as f64).floor();
        let mean = taken as f64 / pixels.max(1) as f64;
        (target >= (mean + 1.0).floor() && target > min as f64)
            .then(|| target.min(MAX_SPP as f64) as u32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Before any sample is measured the schedule plans nothing (the driver then gives
    /// every pixel one sample): a cost of zero per sample once planned MAX_SPP samples in
    /// every pixel of a render whose probe found its deadline passed.
    #[test]
    fn nothing_is_planned_before_a_sample_is_measured() {
        let mut s = PassSchedule::default();
        assert_eq!(s.next_target(10.0, 100, 0, 0), None);
        s.record(0.001, PassWork::default());
        assert_eq!(s.next_target(10.0, 100, 0, 0), None);
        // Once a sample is measured: 1 ms a sample (one thread), 1 s left, 10 pixels.
        s.record(
            0.01,
            PassWork {
                samples: 10,
                sample_ns: 10_000_000,
                ..PassWork::default()
            },
        );
        let t = s.next_target(1.0, 10, 10, 1).unwrap();
        assert!(t > 1 && t < MAX_SPP, "{t}");
    }
}
