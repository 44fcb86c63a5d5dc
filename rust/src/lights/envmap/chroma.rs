//! The colour of an environment map's regions and its peaks, which CAM08's control variate
//! (CAM08 §3, eq. 2; `estimators::control_variate`) scales `L B~ Ṽ` by.
//!
//! A region is a quadtree node of the equal-area octahedral map; its colour is RGB over
//! luminance of `∫ L_c dω` over it. The regions the control variate reads are the nodes one
//! record word covers ([`MAX_REGION_LEVEL`] at most). A region still mixes a sun with the
//! sky around it: 64 regions are 25° across, and the procedural daylight's sun, four texels
//! of a 256² map, carries 58% of its power, so its region's colour was the sun's and the
//! blue sky beside it was scaled as yellow light. The map's *peaks* ([`MapChroma::peaks`]:
//! texels above [`PEAK_FACTOR`] times the mean, at most [`MAX_PEAKS`]) therefore take their
//! own colour, and each region the colour of its other texels. Peaks that form one small
//! disc are the map's sun ([`MapChroma::sun`]).

use glam::Vec3;

use super::{EnvMap, LUMINANCE};
use crate::sampling::octahedral::{morton_decode, morton_encode, texel_center};

#[cfg(test)]
pub(crate) mod tests;

/// The colour of an environment map's regions: per quadtree node of levels
/// `0..=min(MAX_REGION_LEVEL, depth)`, `∫ L_c dω` over its luminance (0 where black). Built
/// once per map; the control variate scales `L B~ Ṽ` by the colour of the region each
/// direction lies in (module docs).
#[derive(Clone, Debug)]
pub struct MapChroma {
    /// The map's quadtree depth (`log2` of its resolution).
    depth: u32,
    /// `chroma[l][j]`: RGB over luminance of node `j` (Morton) of level `l`.
    chroma: Vec<Vec<[f64; 3]>>,
    /// The map's peak texels ([`PEAK_FACTOR`]), by Morton code at `depth`, ascending.
    peaks: Vec<Peak>,
    /// As `chroma`, without the peak texels (`None` without peaks: then `chroma`): the
    /// control variate's region colours.
    rest: Option<Vec<Vec<[f64; 3]>>>,
    /// The peaks' weighted mean direction when they form one small disc ([`sun_of`]).
    sun: Option<Vec3>,
}

/// A texel far brighter than the map's mean (a sun), which the control variate gives its
/// own colour instead of its region's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Peak {
    /// Morton code at the map's depth.
    pub code: u32,
    /// RGB over luminance.
    pub colour: [f64; 3],
    /// The texel's weight in the map's sampling pyramid (its luminance there).
    pub weight: f64,
}

/// A texel of luminance above this many times the map's mean is a peak of [`MapChroma`].
pub const PEAK_FACTOR: f64 = 16.0;

/// Most peaks a [`MapChroma`] keeps (the brightest): each costs a few operations per
/// point in `J`.
pub const MAX_PEAKS: usize = 64;

/// Largest angle (degrees) between a map's peaks and their mean direction for them to be
/// one sun ([`MapChroma::sun`]): the procedural daylight's sun is four texels of a 256² map,
/// about 1° across.
pub const SUN_RADIUS_DEG: f32 = 5.0;

/// Shallowest map with peaks: texels no coarser than any record's
/// ([`crate::sampling::pattern::MAX_LOG2_RESOLUTION`]), so that one record texel holds each
/// peak whole.
pub const MIN_PEAK_DEPTH: u32 = crate::sampling::pattern::MAX_LOG2_RESOLUTION;

/// Finest level of regions a [`MapChroma`] keeps (`4^6` regions; the words of 512² records).
pub const MAX_REGION_LEVEL: u32 = 6;

impl MapChroma {
    /// The region colours of `env`, and its peaks with the regions' colours without them.
    pub fn new(env: &EnvMap) -> Self {
        let res = env.resolution();
        let depth = res.trailing_zeros();
        let mut sums = vec![[0.0f64; 3]; (res * res) as usize];
        for (i, t) in env.texels().iter().enumerate() {
            let (x, y) = (i as u32 % res, i as u32 / res);
            sums[morton_encode(x, y) as usize] = t.map(f64::from);
        }
        // Sum up to level MAX_REGION_LEVEL, then keep that level and the coarser ones.
        let mut levels = Vec::new();
        let mut level = depth;
        loop {
            if level <= MAX_REGION_LEVEL {
                levels.push(sums.clone());
            }
            if level == 0 {
                break;
            }
            sums = sums
                .chunks_exact(4)
                .map(|c| std::array::from_fn(|k| (c[0][k] + c[1][k]) + (c[2][k] + c[3][k])))
                .collect();
            level -= 1;
        }
        levels.reverse();
        let peaks = find_peaks(env);
        let colours = |levels: &[Vec<[f64; 3]>]| -> Vec<Vec<[f64; 3]>> {
            levels
                .iter()
                .map(|level| level.iter().map(|&rgb| over_luminance(rgb)).collect())
                .collect()
        };
        let chroma = colours(&levels);
        let rest = (!peaks.is_empty()).then(|| {
            // Each region's sums without the peak texels it holds.
            for peak in &peaks {
                let rgb = texel_rgb(env, peak.code);
                for (l, level) in levels.iter_mut().enumerate() {
                    let region = (peak.code >> (2 * (depth - l as u32))) as usize;
                    level[region] = std::array::from_fn(|k| level[region][k] - rgb[k]);
                }
            }
            colours(&levels)
        });
        let sun = sun_of(&peaks, res);
        Self {
            depth,
            chroma,
            peaks,
            rest,
            sun,
        }
    }

    /// The control variate's colour of the texel of `code` at the map's depth, read at
    /// region level `level`: the peak's own colour if it is one, else its region's
    /// without the peaks.
    #[inline]
    pub fn control_colour(&self, code: u32, level: u32) -> [f64; 3] {
        self.control_colour_of(code, level).0
    }

    /// [`Self::control_colour`], and whether the texel is a peak.
    #[inline]
    pub fn control_colour_of(&self, code: u32, level: u32) -> ([f64; 3], bool) {
        match self.peak_index(code) {
            Some(i) => (self.peaks[i].colour, true),
            None => {
                let region = (code >> (2 * (self.depth - level))) as usize;
                (self.control_colours(level)[region], false)
            }
        }
    }

    /// The index in [`Self::peaks`] of the texel of `code` (at the map's depth), if it is
    /// a peak.
    #[inline]
    pub fn peak_index(&self, code: u32) -> Option<usize> {
        self.peaks.binary_search_by_key(&code, |p| p.code).ok()
    }

    /// The direction of the map's sun: the peaks' mean direction weighted by their
    /// luminance, when every peak lies within [`SUN_RADIUS_DEG`] of it (`None` without
    /// peaks or where they are spread: a bright horizon, two suns). The control variate
    /// takes `Ṽ` on the peaks from one shadow ray toward it
    /// ([`Interpolant::with_sun`](crate::visibility::cache::interpolant::Interpolant::with_sun)).
    pub fn sun(&self) -> Option<Vec3> {
        self.sun
    }

    /// The control variate's region colours at `level` (without the peak texels).
    pub fn control_colours(&self, level: u32) -> &[[f64; 3]] {
        &self.rest.as_ref().unwrap_or(&self.chroma)[level as usize]
    }

    /// The map's peak texels, by code.
    pub fn peaks(&self) -> &[Peak] {
        &self.peaks
    }

    /// RGB over luminance per node of `level <= min(MAX_REGION_LEVEL, depth)`.
    pub fn chroma(&self, level: u32) -> &[[f64; 3]] {
        &self.chroma[level as usize]
    }

    /// The map's quadtree depth: its texels are level `depth`.
    pub fn depth(&self) -> u32 {
        self.depth
    }
}

/// [`MapChroma::sun`] of `peaks` on a map of `res` texels a side.
fn sun_of(peaks: &[Peak], res: u32) -> Option<Vec3> {
    let direction = |p: &Peak| texel_center(morton_decode(p.code), res);
    let sum: Vec3 = peaks.iter().map(|p| direction(p) * p.weight as f32).sum();
    let mean = sum.try_normalize()?;
    let cos_max = SUN_RADIUS_DEG.to_radians().cos();
    peaks
        .iter()
        .all(|p| direction(p).dot(mean) >= cos_max)
        .then_some(mean)
}

/// RGB over luminance (0 where the luminance is not positive).
fn over_luminance(rgb: [f64; 3]) -> [f64; 3] {
    let y: f64 = rgb.iter().zip(LUMINANCE).map(|(c, w)| c * w).sum();
    if y > 0.0 {
        rgb.map(|c| c / y)
    } else {
        [0.0; 3]
    }
}

/// The RGB radiance of the map's texel of Morton code `code` (at the map's depth).
fn texel_rgb(env: &EnvMap, code: u32) -> [f64; 3] {
    env.texel(morton_decode(code)).as_dvec3().to_array()
}

/// The texels of `env` whose sampling weight exceeds [`PEAK_FACTOR`] times the mean, the
/// [`MAX_PEAKS`] heaviest, by code; none for maps shallower than [`MIN_PEAK_DEPTH`].
fn find_peaks(env: &EnvMap) -> Vec<Peak> {
    let res = env.resolution();
    let depth = res.trailing_zeros();
    let Some(dist) = env.distribution() else {
        return Vec::new();
    };
    if depth < MIN_PEAK_DEPTH || dist.depth() != depth {
        return Vec::new();
    }
    let weights = dist.level(depth);
    let mean = weights.iter().sum::<f64>() / weights.len() as f64;
    let mut peaks: Vec<Peak> = weights
        .iter()
        .enumerate()
        .filter(|&(_, &w)| w > PEAK_FACTOR * mean)
        .map(|(code, &weight)| Peak {
            code: code as u32,
            colour: over_luminance(texel_rgb(env, code as u32)),
            weight,
        })
        .collect();
    peaks.sort_by(|a, b| b.weight.total_cmp(&a.weight).then(a.code.cmp(&b.code)));
    peaks.truncate(MAX_PEAKS);
    peaks.sort_by_key(|p| p.code);
    peaks
}
