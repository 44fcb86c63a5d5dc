//! Each pixel's mixture of sampling techniques after the adaptive pilot (method "product"
//! with adaptive counts): the pilot's draws at every pixel give the second moment each of
//! a few candidate mixtures would have had ([`DrawMoments`]), and every pixel then takes
//! the one of least moment over its neighbours' draws ([`PixelTechniques`]), the pixel
//! itself excluded so that its count of each stays independent of its own samples.

use super::Techniques;
use crate::math::WINDOW_RADIUS;

/// The mixtures a pixel of method "product" may take after the pilot
/// ([`PixelTechniques`]), besides the image's own (learnt from the probe, or given):
/// from mostly the product to mostly BSDF sampling, two with more of the map's own
/// distribution and three without it (where the map's peak is mostly hidden, as under
/// panels, its draws are wasted). BSDF sampling keeps 0.05 at least, so that every one is
/// unbiased at any hit.
pub const CANDIDATES: [Techniques; 10] = [
    Techniques::new(0.9, 0.0, 0.05, 0.05),
    Techniques::new(0.7, 0.0, 0.2, 0.1),
    Techniques::new(0.5, 0.0, 0.45, 0.05),
    Techniques::new(0.3, 0.0, 0.6, 0.1),
    Techniques::new(0.1, 0.0, 0.8, 0.1),
    Techniques::new(0.5, 0.0, 0.2, 0.3),
    Techniques::new(0.3, 0.0, 0.35, 0.35),
    Techniques::new(0.8, 0.0, 0.2, 0.0),
    Techniques::new(0.5, 0.0, 0.5, 0.0),
    Techniques::new(0.2, 0.0, 0.8, 0.0),
];
/// The image's mixture and the [`CANDIDATES`].
pub const CHOICES: usize = CANDIDATES.len() + 1;

/// The mixtures a pixel may take after the pilot, the image's first, with each one's
/// technique probabilities where a product can draw: made once per pass, read at every
/// draw of the pilot ([`DrawMoments::add`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Choices {
    options: [Techniques; CHOICES],
    probabilities: [[f64; 4]; CHOICES],
}

impl Choices {
    /// The image's mixture `image` and the [`CANDIDATES`].
    pub fn new(image: Techniques) -> Self {
        let mut options = [image; CHOICES];
        options[1..].copy_from_slice(&CANDIDATES);
        Self::of(options)
    }

    /// Every option with `share` of its product weight kept
    /// ([`Techniques::with_product_share`]): the mixtures a glossy hit's diffuse product
    /// is drawn with.
    pub fn with_product_share(&self, share: f32) -> Self {
        Self::of(self.options.map(|t| t.with_product_share(share)))
    }

    fn of(options: [Techniques; CHOICES]) -> Self {
        Self {
            options,
            probabilities: options.map(|t| t.probabilities(true, false, true)),
        }
    }
}
/// Fewest draws a window must hold for its pixel to leave the image's mixture.
pub const MIN_WINDOW_DRAWS: u32 = 64;

/// The pilot's draws at one pixel, as the second moment each of [`CHOICES`] would give:
/// a draw of value `f` (luminance of `f cos L V`), drawn with density `p₀`, where the
/// techniques' own densities are `p_t`, adds `f² / (q_k p₀)` with `q_k = Σ c_kt p_t`, an
/// unbiased estimate of mixture `k`'s `∫ f² / q_k` ([`crate::estimators::direct::Techniques::learnt`]'s
/// objective, per pixel).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DrawMoments {
    sums: [f64; CHOICES],
    draws: u32,
}

impl DrawMoments {
    /// Adds one draw, of value `value` drawn with density `pdf`, where the techniques'
    /// own densities are `pdfs`.
    #[inline]
    pub fn add(&mut self, choices: &Choices, value: f64, pdfs: [f64; 4], pdf: f64) {
        self.draws += 1;
        if !(value > 0.0 && pdf > 0.0) {
            return;
        }
        for (sum, c) in self.sums.iter_mut().zip(&choices.probabilities) {
            let q: f64 = c.iter().zip(&pdfs).map(|(c, p)| c * p).sum();
            *sum += if q > 0.0 {
                value * value / (q * pdf)
            } else {
                f64::INFINITY
            };
        }
    }

    /// Draws added.
    pub fn draws(&self) -> u32 {
        self.draws
    }
}

/// Each pixel's mixture after the pilot: the choice of least second moment over the
/// draws of its window, the pixel excluded (unbiased for the reason the shares are), or
/// the image's where the window held fewer than [`MIN_WINDOW_DRAWS`] draws that saw light.
/// Each neighbour counts by its moments relative to the image mixture's, so that a
/// sunlit neighbour does not choose for a pixel in shadow (on panels, by absolute
/// moments most of the shadowed ground kept the product-heavy mixture the sunlit
/// ground wants).
#[derive(Clone, Debug, PartialEq)]
pub struct PixelTechniques {
    options: [Techniques; CHOICES],
    choice: Vec<u8>,
}

impl PixelTechniques {
    /// Choices among `choices` from the pilot's `moments` of a `width x height` image
    /// (row-major).
    pub fn measure(
        moments: &[DrawMoments],
        choices: &Choices,
        width: usize,
        height: usize,
    ) -> Self {
        debug_assert_eq!(moments.len(), width * height);
        let options = choices.options;
        let choice = (0..moments.len())
            .map(|i| {
                let (x, y, r) = (i % width, i / width, WINDOW_RADIUS);
                let (mut sums, mut draws) = ([0.0f64; CHOICES], 0u32);
                for yy in y.saturating_sub(r)..(y + r + 1).min(height) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(width) {
                        let m = &moments[yy * width + xx];
                        if (xx, yy) != (x, y) && m.sums[0] > 0.0 {
                            draws += m.draws;
                            for (s, v) in sums.iter_mut().zip(&m.sums) {
                                *s += v / m.sums[0];
                            }
                        }
                    }
                }
                if draws < MIN_WINDOW_DRAWS {
                    return 0;
                }
                // The first of the least (the image's on ties).
                (0..CHOICES).fold(0, |best, k| if sums[k] < sums[best] { k } else { best }) as u8
            })
            .collect();
        Self { options, choice }
    }

    /// Pixel `i`'s mixture.
    #[inline]
    pub fn get(&self, i: usize) -> &Techniques {
        &self.options[self.choice[i] as usize]
    }

    /// How many pixels took each choice (the image's mixture first).
    pub fn counts(&self) -> [u64; CHOICES] {
        let mut counts = [0u64; CHOICES];
        for &c in &self.choice {
            counts[c as usize] += 1;
        }
        counts
    }
}

#[cfg(test)]
mod tests;
