use glam::UVec2;

use super::*;
use crate::lights::procedural::sky;

/// A sky with a sun: peaks of their own colour (shared by the interpolant's tests).
pub(crate) fn test_sky(res: u32) -> EnvMap {
    let sun = Vec3::new(0.4, 0.6, -0.5).normalize();
    sky(
        sun,
        [2e3, 1.5e3, 1e3],
        6.0,
        [0.2, 0.3, 0.6],
        [0.8, 0.8, 0.9],
        res,
    )
    .unwrap()
}

/// Whether `a` is within `rel` of `b` in every channel.
pub(crate) fn close(a: [f64; 3], b: [f64; 3], rel: f64) -> bool {
    (0..3).all(|c| (a[c] - b[c]).abs() <= rel * b[c].abs().max(1e-300))
}

#[test]
fn map_chroma_is_the_colour_of_each_region() {
    for res in [1u32, 4, 64] {
        let env = test_sky(res);
        let c = MapChroma::new(&env);
        assert_eq!(c.depth(), res.trailing_zeros());
        // Level 0 is the whole map's colour.
        let total = env.total_power();
        let y: f64 = total.iter().zip(LUMINANCE).map(|(a, b)| a * b).sum();
        assert!(close(c.chroma(0)[0], total.map(|t| t / y), 1e-12));
        for level in 0..=MAX_REGION_LEVEL.min(c.depth()) {
            assert_eq!(c.chroma(level).len(), 1 << (2 * level));
            for rgb in c.chroma(level) {
                let y: f64 = rgb.iter().zip(LUMINANCE).map(|(a, b)| a * b).sum();
                assert!((y - 1.0).abs() < 1e-12, "{rgb:?}");
            }
        }
    }
    let black = EnvMap::constant([0.0; 3], 8).unwrap();
    assert!(MapChroma::new(&black)
        .chroma(2)
        .iter()
        .all(|c| *c == [0.0; 3]));
}

/// The sun's texels are the map's peaks, each with its own colour; the control
/// variate's region colours are those of the rest of each region.
#[test]
fn peaks_are_the_sun_and_regions_keep_the_rest_of_their_colour() {
    let env = test_sky(256);
    let c = MapChroma::new(&env);
    let depth = c.depth();
    let dist = env.distribution().unwrap();
    let weights = dist.level(depth);
    let mean = weights.iter().sum::<f64>() / weights.len() as f64;
    let bright: Vec<u32> = (0..weights.len() as u32)
        .filter(|&t| weights[t as usize] > PEAK_FACTOR * mean)
        .collect();
    assert!(!bright.is_empty() && bright.len() <= MAX_PEAKS);
    assert_eq!(c.peaks().iter().map(|p| p.code).collect::<Vec<_>>(), bright);
    let level = 3;
    let rgb = |t: u32| texel_rgb(&env, t);
    for peak in c.peaks() {
        assert!(close(peak.colour, over_luminance(rgb(peak.code)), 1e-12));
        assert_eq!(c.control_colour(peak.code, level), peak.colour);
        // Its region's colour is that of the region's other texels.
        let region = peak.code >> (2 * (depth - level));
        let others: Vec<u32> = (0..weights.len() as u32)
            .filter(|&t| t >> (2 * (depth - level)) == region && bright.binary_search(&t).is_err())
            .collect();
        let sum = others.iter().fold([0.0; 3], |a, &t| {
            let x = rgb(t);
            std::array::from_fn(|k| a[k] + x[k])
        });
        let expect = over_luminance(sum);
        assert!(close(
            c.control_colours(level)[region as usize],
            expect,
            1e-9
        ));
        assert_eq!(
            c.control_colour(others[0], level),
            c.control_colours(level)[region as usize]
        );
        // The sky around the sun is bluer than the region with the sun was.
        assert!(expect[2] > c.chroma(level)[region as usize][2]);
    }
    // No peaks: the control colours are the regions'.
    let grey = EnvMap::constant([0.5; 3], 256).unwrap();
    let g = MapChroma::new(&grey);
    assert!(g.peaks().is_empty());
    assert_eq!(g.control_colours(3), g.chroma(3));
}

#[test]
fn peaks_apart_are_no_sun() {
    let res = 256;
    let peak = |x: u32, y: u32| Peak {
        code: morton_encode(x, y),
        colour: [1.0; 3],
        weight: 1.0,
    };
    // Two texels side by side are one sun at their mean.
    let near = [peak(100, 40), peak(101, 40)];
    let d = sun_of(&near, res).unwrap();
    let a = texel_center(UVec2::new(100, 40), res);
    let b = texel_center(UVec2::new(101, 40), res);
    assert!((d - (a + b).normalize()).length() < 1e-6);
    // A quarter of the sky apart: two suns, or a bright horizon.
    assert_eq!(sun_of(&[peak(100, 40), peak(40, 100)], res), None);
    assert_eq!(sun_of(&[], res), None);
}
