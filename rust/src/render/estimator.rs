//! What a method supplies to the pass layer ([`super::passes`]): the per-pixel sampling of
//! one pass ([`PixelPass`]) and the few decisions it makes between passes
//! ([`PixelEstimator`]). Everything else — which pixels a pass covers and how many samples
//! each takes, the time budget, progress, Ctrl-C, determinism across threads and the
//! counts in the stats — is the driver's, so a method writes none of it.

use std::ops::Range;

use super::adaptive::SampleShares;
use super::sums::PixelSums;

/// What the driver tells a method about the pass it is about to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PassPlan {
    /// Passes made before this one.
    pub index: u32,
    /// The first pass of a budgeted render: a few samples in every
    /// pass-schedule stride of bands, whose timing sizes the passes that
    /// follow. A method may measure what it wants to learn here.
    pub probe: bool,
    /// The pilot of adaptive counts: the pixel notes ([`PixelEstimator::Note`]) of this pass
    /// reach [`PixelEstimator::after_pilot`].
    pub pilot: bool,
}

/// CPU time one pixel of a pass took, as the pass schedule models it: the pixel's set-up
/// (its anchor's work, done once per pass) and its samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PixelTiming {
    /// Nanoseconds of the pixel's set-up.
    pub anchor_ns: u64,
    /// Nanoseconds of its samples.
    pub sample_ns: u64,
}

/// The counters of one band of a pass, added up over bands and passes.
pub trait Merge: Default + Send {
    /// Adds `other` (a band done after this one, in band order) to `self`.
    fn merge(&mut self, other: Self);
}

impl Merge for () {
    fn merge(&mut self, _: Self) {}
}

/// One pixel of a band, as the driver hands it to [`PixelPass::shade_band`].
#[derive(Debug)]
pub struct BandPixel<'a, S, N> {
    /// Row-major index in the image.
    pub pixel: usize,
    /// Samples the pass brings the pixel to: samples `acc.samples()..target` are due (none
    /// when `target <= acc.samples()`).
    pub target: u32,
    /// The pixel's accumulator, kept across passes.
    pub acc: &'a mut S,
    /// The pixel's note ([`PixelPass::Note`]), kept across passes.
    pub note: &'a mut N,
    /// What shading the pixel took in this pass; the method fills it in (zero: nothing).
    pub timing: PixelTiming,
}

/// [`PixelPass::shade_band`]'s default: the band's pixels one by one through
/// [`PixelPass::shade_pixel`], in order, checking `stop` before each.
pub fn shade_pixels<P: PixelPass + ?Sized>(
    pass: &P,
    pixels: &mut [BandPixel<'_, P::Sums, P::Note>],
    work: &mut P::Work,
    stop: &dyn Fn() -> bool,
) {
    for p in pixels {
        // A band of many samples takes seconds; stop within a pixel.
        if stop() {
            break;
        }
        if p.acc.due(p.target) {
            let current = p.acc.samples();
            let samples = current..p.target.max(current);
            p.timing = pass.shade_pixel(p.pixel, samples, p.acc, work, p.note);
        }
    }
}

/// One pass's per-pixel sampling. Shared by the workers: `&self` only.
pub trait PixelPass: Sync {
    /// Counters and scratch of one band (a run of rows one worker shades in order).
    type Work: Merge;
    /// What the method keeps per pixel from the adaptive pilot.
    type Note: Default + Clone + Send + Sync;
    /// A pixel's accumulator ([`super::sums::CvSums`] for most methods).
    type Sums: PixelSums;

    /// Draws samples `samples` of `pixel` (row-major index) into `acc`, in sample order
    /// (none when the pixel is due at its target: [`PixelSums::due`]).
    /// Every random number must come from `(seed, pixel, sample, dimension)`, never from
    /// `work`'s state, so that the image does not depend on which worker shades the pixel.
    /// `note` is the pixel's, kept across passes.
    fn shade_pixel(
        &self,
        pixel: usize,
        samples: Range<u32>,
        acc: &mut Self::Sums,
        work: &mut Self::Work,
        note: &mut Self::Note,
    ) -> PixelTiming;

    /// Shades one band: `pixels` are whole rows of the image (row-major, in order; the
    /// driver's bands start at a multiple of their rows, [`super::passes::BAND_ROWS`] with
    /// even counts), each brought to its target in sample order with its timing filled in.
    /// When `stop()` turns true the method stops soon (between pixels or samples); every
    /// pixel keeps the samples it took, and the driver counts them from the sums.
    ///
    /// The default shades pixel by pixel ([`shade_pixels`]). A method whose samples are
    /// cheaper together (the many-light gather traces a 4 x 4 tile's rays towards a light
    /// as one packet) overrides it; whatever it groups, a pixel's values must be those
    /// [`Self::shade_pixel`] would give (every random number from `(seed, pixel, sample,
    /// dimension)`, added in sample order), so the image depends neither on the grouping
    /// nor on the workers.
    fn shade_band(
        &self,
        pixels: &mut [BandPixel<'_, Self::Sums, Self::Note>],
        work: &mut Self::Work,
        stop: &dyn Fn() -> bool,
    ) {
        shade_pixels(self, pixels, work, stop)
    }
}

/// A method the pass layer drives: it runs passes ([`Self::pass`]) and may learn between
/// them. The hooks have defaults, so a method with nothing to learn writes
/// [`Self::pass`] alone.
pub trait PixelEstimator {
    /// [`PixelPass::Work`] of its passes.
    type Work: Merge;
    /// [`PixelPass::Note`] of its passes.
    type Note: Default + Clone + Send + Sync;
    /// [`PixelPass::Sums`] of its passes.
    type Sums: PixelSums;
    /// Whether it can take adaptive counts ([`Self::shares`]).
    const ADAPTS: bool = false;
    /// Whether it learns from the probe pass of a budgeted render ([`Self::end_pass`] on a
    /// probe): its probe then runs whole, so that what it learns is a function of the seed
    /// alone, whatever the timing. Otherwise the probe starts bands only within a share of
    /// the budget, so a method whose samples are dear does not spend the budget on it.
    const LEARNS_FROM_PROBE: bool = false;
    /// One pass, borrowing what it reads for as long as the pass runs (a cache's read
    /// lock, say).
    type Pass<'a>: PixelPass<Work = Self::Work, Note = Self::Note, Sums = Self::Sums>
    where
        Self: 'a;

    /// Makes the pass `plan` describes and hands it to `run`, which shades the pixels.
    fn pass<R>(&self, plan: &PassPlan, run: impl FnOnce(&Self::Pass<'_>) -> R) -> R;

    /// After pass `plan`, with its bands' work in band order and every pixel's sums so far.
    fn end_pass(&mut self, _plan: &PassPlan, _works: &[Self::Work], _sums: &[Self::Sums]) {}

    /// After the adaptive pilot, with every pixel's note from it (row-major).
    fn after_pilot(&mut self, _notes: &[Self::Note], _width: usize, _height: usize) {}

    /// After the adaptive pilot (only where [`Self::ADAPTS`]): each pixel's share of the
    /// samples to come, measured from every pixel's sums so far and, under a budget, each
    /// pixel's CPU nanoseconds per sample in its latest pass (`costs`).
    fn shares(
        &self,
        _sums: &[Self::Sums],
        _costs: Option<&[f32]>,
        _width: usize,
        _height: usize,
    ) -> Option<SampleShares> {
        None
    }
}
