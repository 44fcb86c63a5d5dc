//! Procedural environment maps: a gradient sky with a disc sun ([`sky`]), bright
//! rectangular "windows" of directions on a dim background ([`windows`], the kind of
//! lighting CAM08's garage scene is lit by), and a constant map ([`constant`]).
//!
//! Directions are given as azimuth and elevation in degrees, in the lat-long convention of
//! [`super::envmap`]: azimuth 0 looks toward -z, 90 toward +x, 180 toward +z, 270 toward
//! -x; elevation is the angle above the horizon (+90 is +y). Texels are averaged over
//! 4x4 sub-samples; the sun's power is made exact (see [`sky`]).

use glam::{DVec3, UVec2, Vec2, Vec3};
use rayon::prelude::*;

use super::envmap::{check_resolution, supersample, EnvMap};
use crate::error::{Error, Result};
use crate::sampling::octahedral::{square_to_sphere, texel_center, texel_of};

/// Radiance below the horizon of [`sky`], as a fraction of the horizon's, reached at the
/// nadir.
pub const GROUND_FACTOR: f32 = 0.25;

/// Unit direction of `azimuth_deg` / `elevation_deg` (see the module docs).
pub fn direction(azimuth_deg: f32, elevation_deg: f32) -> Vec3 {
    let (sa, ca) = (azimuth_deg as f64).to_radians().sin_cos();
    let (se, ce) = (elevation_deg as f64).to_radians().sin_cos();
    DVec3::new(sa * ce, se, -ca * ce).as_vec3()
}

fn check_rgb(v: [f32; 3], name: &str) -> Result<()> {
    if super::valid_radiance(v) {
        Ok(())
    } else {
        Err(Error::invalid(name, super::radiance_problem(v)))
    }
}

fn lerp(a: [f32; 3], b: [f32; 3], t: f64) -> DVec3 {
    let (a, b) = (Vec3::from(a).as_dvec3(), Vec3::from(b).as_dvec3());
    a + (b - a) * t
}

/// The sky without the sun: `lerp(horizon, zenith, sqrt(y))` above the horizon and
/// `lerp(horizon, GROUND_FACTOR · horizon, sqrt(-y))` below it, for unit `d`.
pub fn sky_gradient(d: DVec3, zenith: [f32; 3], horizon: [f32; 3]) -> DVec3 {
    if d.y >= 0.0 {
        lerp(horizon, zenith, d.y.min(1.0).sqrt())
    } else {
        let ground = horizon.map(|c| c * GROUND_FACTOR);
        lerp(horizon, ground, (-d.y).min(1.0).sqrt())
    }
}

/// A smooth gradient sky (see [`sky_gradient`]) with a sun: a disc of angular diameter
/// `sun_angle_deg` in `(0, 90]` degrees around `sun_dir` (any non-zero length) of uniform
/// radiance `sun_radiance`, replacing the sky it covers. Texels on the disc's edge get its
/// covered fraction (16x16 sub-samples; 4x4 for a disc over more than 16384 texels), rescaled so that the sun's power
/// `sun_radiance · 2π(1 - cos(sun_angle_deg / 2))` is exact even when the disc is smaller
/// than a texel (then the texel containing `sun_dir` takes it all). The real sun is
/// 0.53° across. Radiances are finite and `>= 0`; `resolution` is a power of two in
/// `[1, 4096]`.
pub fn sky(
    sun_dir: Vec3,
    sun_radiance: [f32; 3],
    sun_angle_deg: f32,
    zenith: [f32; 3],
    horizon: [f32; 3],
    resolution: u32,
) -> Result<EnvMap> {
    check_resolution(resolution, "resolution")?;
    if !(sun_dir.is_finite() && sun_dir.length() > 0.0) {
        return Err(Error::invalid(
            "sun_dir",
            format!("must be a finite, non-zero vector, got {sun_dir}"),
        ));
    }
    check_rgb(sun_radiance, "sun_radiance")?;
    if !(sun_angle_deg > 0.0 && sun_angle_deg <= 90.0) {
        return Err(Error::invalid(
            "sun_angle_deg",
            format!("must be in (0, 90] degrees, got {sun_angle_deg}"),
        ));
    }
    check_rgb(zenith, "zenith")?;
    check_rgb(horizon, "horizon")?;
    let res = resolution;
    let sun = sun_dir.as_dvec3().normalize();
    let radius = (sun_angle_deg as f64 * 0.5).to_radians();
    let cos_radius = radius.cos();
    let mut texels = supersample(res, 4, |d| sky_gradient(d, zenith, horizon));
    let sun_rgb = Vec3::from(sun_radiance).as_dvec3();
    if sun_rgb != DVec3::ZERO {
        let omega_texel = 4.0 * std::f64::consts::PI / (res as f64 * res as f64);
        let omega_sun = std::f64::consts::TAU * (1.0 - cos_radius);
        // Fraction of each texel the disc covers; only texels near the disc can be touched
        // (texels span at most ~3 nominal widths along a side).
        let margin = radius + 4.0 * omega_texel.sqrt();
        let near: Vec<usize> = (0..res * res)
            .filter(|&i| {
                let c = texel_center(UVec2::new(i % res, i / res), res);
                c.as_dvec3().dot(sun).clamp(-1.0, 1.0).acos() <= margin
            })
            .map(|i| i as usize)
            .collect();
        // 16x16 sub-samples, fewer if the disc covers very many texels.
        let sub = if near.len() <= 1 << 14 { 16 } else { 4 };
        let mut covered: Vec<(usize, f64)> = near
            .par_iter()
            .map(|&i| {
                let t = UVec2::new(i as u32 % res, i as u32 / res);
                let mut hits = 0u32;
                for sy in 0..sub {
                    for sx in 0..sub {
                        let within = (Vec2::new(sx as f32, sy as f32) + 0.5) / sub as f32;
                        let d = square_to_sphere((t.as_vec2() + within) / res as f32);
                        hits += (d.as_dvec3().dot(sun) >= cos_radius) as u32;
                    }
                }
                (i, hits as f64 / (sub * sub) as f64)
            })
            .filter(|(_, c)| *c > 0.0)
            .collect();
        let total: f64 = covered.iter().map(|(_, c)| c * omega_texel).sum();
        if total > 0.0 {
            let scale = omega_sun / total;
            for (_, c) in &mut covered {
                *c *= scale;
            }
        } else {
            let t = texel_of(sun.as_vec3(), res);
            covered = vec![((t.y * res + t.x) as usize, omega_sun / omega_texel)];
        }
        for (i, c) in covered {
            let s = Vec3::from(texels[i]).as_dvec3();
            texels[i] = (s * (1.0 - c.min(1.0)) + sun_rgb * c).as_vec3().to_array();
        }
    }
    EnvMap::from_octahedral(res, texels)
}

/// A rectangle of directions for [`windows`]: azimuths within `width_deg / 2` of
/// `azimuth_deg` (wrapping around) and elevations within `height_deg / 2` of
/// `elevation_deg` (clipped to [-90, 90]), of uniform `radiance`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Window {
    /// Azimuth of the centre, degrees (0: -z, 90: +x, 180: +z, 270: -x).
    pub azimuth_deg: f32,
    /// Elevation of the centre above the horizon, degrees in [-90, 90].
    pub elevation_deg: f32,
    /// Extent in azimuth, degrees in (0, 360].
    pub width_deg: f32,
    /// Extent in elevation, degrees in (0, 180].
    pub height_deg: f32,
    /// Radiance inside, finite and `>= 0` per channel.
    pub radiance: [f32; 3],
}

impl Window {
    /// Whether unit direction `d` lies in the window.
    pub fn contains(&self, d: DVec3) -> bool {
        let elevation = d.y.clamp(-1.0, 1.0).asin().to_degrees();
        if (elevation - self.elevation_deg as f64).abs() > 0.5 * self.height_deg as f64 {
            return false;
        }
        let azimuth = d.x.atan2(-d.z).to_degrees();
        let diff = (azimuth - self.azimuth_deg as f64 + 180.0).rem_euclid(360.0) - 180.0;
        diff.abs() <= 0.5 * self.width_deg as f64
    }

    /// Solid angle of the window in steradians.
    pub fn solid_angle(&self) -> f64 {
        let lo = (self.elevation_deg as f64 - 0.5 * self.height_deg as f64).max(-90.0);
        let hi = (self.elevation_deg as f64 + 0.5 * self.height_deg as f64).min(90.0);
        (self.width_deg as f64).to_radians() * (hi.to_radians().sin() - lo.to_radians().sin())
    }

    fn check(&self, i: usize) -> Result<()> {
        let name = format!("windows[{i}]");
        let bad = |what: String| Err(Error::invalid(name.clone(), what));
        if !self.azimuth_deg.is_finite() {
            return bad(format!(
                "azimuth_deg must be finite, got {}",
                self.azimuth_deg
            ));
        }
        if !(-90.0..=90.0).contains(&self.elevation_deg) {
            return bad(format!(
                "elevation_deg must be in [-90, 90], got {}",
                self.elevation_deg
            ));
        }
        if !(self.width_deg > 0.0 && self.width_deg <= 360.0) {
            return bad(format!(
                "width_deg must be in (0, 360], got {}",
                self.width_deg
            ));
        }
        if !(self.height_deg > 0.0 && self.height_deg <= 180.0) {
            return bad(format!(
                "height_deg must be in (0, 180], got {}",
                self.height_deg
            ));
        }
        check_rgb(self.radiance, &format!("windows[{i}].radiance"))
    }
}

/// A dim `background` with bright rectangular `windows` of directions (later windows
/// cover earlier ones where they overlap): CAM08's garage-style lighting, where a few
/// large, very bright regions carry most of the power. Texels average 4x4 sub-samples.
pub fn windows(windows: &[Window], background: [f32; 3], resolution: u32) -> Result<EnvMap> {
    check_resolution(resolution, "resolution")?;
    check_rgb(background, "background")?;
    for (i, w) in windows.iter().enumerate() {
        w.check(i)?;
    }
    let bg = Vec3::from(background).as_dvec3();
    let texels = supersample(resolution, 4, |d| {
        windows
            .iter()
            .rev()
            .find(|w| w.contains(d))
            .map_or(bg, |w| Vec3::from(w.radiance).as_dvec3())
    });
    EnvMap::from_octahedral(resolution, texels)
}

/// A uniform map of `radiance` ([`EnvMap::constant`]).
pub fn constant(radiance: [f32; 3], resolution: u32) -> Result<EnvMap> {
    EnvMap::constant(radiance, resolution)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clear_sky(sun: Vec3, angle: f32, res: u32) -> EnvMap {
        sky(sun, [5e4; 3], angle, [0.3, 0.5, 1.0], [0.9, 0.9, 0.85], res).unwrap()
    }

    #[test]
    fn directions_follow_the_latlong_convention() {
        assert!((direction(0.0, 0.0) - Vec3::NEG_Z).length() < 1e-6);
        assert!((direction(90.0, 0.0) - Vec3::X).length() < 1e-6);
        assert!((direction(180.0, 0.0) - Vec3::Z).length() < 1e-6);
        assert!((direction(0.0, 90.0) - Vec3::Y).length() < 1e-6);
    }

    #[test]
    fn the_sun_has_exactly_its_power_at_any_size() {
        let sun = direction(40.0, 30.0);
        for (angle, res) in [(0.53, 64), (0.53, 512), (5.0, 32), (30.0, 64), (1e-3, 16)] {
            let with = clear_sky(sun, angle, res).total_power();
            let without = sky(sun, [0.0; 3], angle, [0.3, 0.5, 1.0], [0.9, 0.9, 0.85], res)
                .unwrap()
                .total_power();
            let omega = std::f64::consts::TAU * (1.0 - (0.5 * angle as f64).to_radians().cos());
            let sun_power = with[0] - without[0];
            // The disc replaces the sky under it: its power is the sun's minus that sky's.
            let expected = 5e4 * omega;
            assert!(
                (sun_power - expected).abs() <= 0.01 * expected + 1.0 * omega + 1e-9,
                "angle {angle} res {res}: {sun_power} vs {expected}"
            );
            if angle < 0.5 {
                continue;
            }
            // The brightest texel is on the sun.
            let map = clear_sky(sun, angle, res);
            let i = (0..map.texels().len())
                .max_by(|&a, &b| map.texels()[a][0].total_cmp(&map.texels()[b][0]))
                .unwrap() as u32;
            let c =
                crate::sampling::octahedral::texel_center(glam::UVec2::new(i % res, i / res), res);
            let reach = (0.5 * angle).to_radians() + 3.0 * (12.57 / (res * res) as f32).sqrt();
            assert!(c.dot(sun) >= reach.cos(), "angle {angle} res {res}");
        }
    }

    #[test]
    fn the_gradient_runs_from_horizon_to_zenith() {
        let m = sky(Vec3::Y, [0.0; 3], 1.0, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], 64).unwrap();
        let up = m.eval(Vec3::Y);
        let side = m.eval(Vec3::new(1.0, 0.01, 0.0));
        let down = m.eval(Vec3::NEG_Y);
        assert!(up.z > 0.9 && up.x < 0.1, "{up}");
        assert!(side.x > 0.5 && side.z < 0.5, "{side}");
        assert!((down.x - GROUND_FACTOR).abs() < 0.05, "{down}");
    }

    #[test]
    fn windows_are_bright_where_placed_and_the_background_elsewhere() {
        let w = Window {
            azimuth_deg: 90.0,
            elevation_deg: 30.0,
            width_deg: 40.0,
            height_deg: 20.0,
            radiance: [100.0, 90.0, 80.0],
        };
        let m = windows(&[w], [0.05; 3], 128).unwrap();
        assert_eq!(
            m.eval(direction(90.0, 30.0)).to_array(),
            [100.0, 90.0, 80.0]
        );
        assert_eq!(m.eval(direction(270.0, 30.0)).to_array(), [0.05; 3]);
        let p = m.total_power()[0];
        let expected =
            100.0 * w.solid_angle() + 0.05 * (4.0 * std::f64::consts::PI - w.solid_angle());
        assert!((p - expected).abs() < 0.02 * expected, "{p} vs {expected}");
        // A window across azimuth 0 wraps.
        let wrap = Window {
            azimuth_deg: 350.0,
            ..w
        };
        let m = windows(&[wrap], [0.0; 3], 64).unwrap();
        assert!(m.eval(direction(5.0, 30.0)).x > 0.0);
        assert!(m.eval(direction(330.0, 30.0)).x > 0.0);
        assert_eq!(m.eval(direction(300.0, 30.0)).x, 0.0);
    }

    #[test]
    fn bad_arguments_name_themselves() {
        let ok = [1.0f32; 3];
        let cases = [
            sky(Vec3::ZERO, ok, 1.0, ok, ok, 16).unwrap_err(),
            sky(Vec3::Y, [f32::NAN, 0.0, 0.0], 1.0, ok, ok, 16).unwrap_err(),
            sky(Vec3::Y, ok, 0.0, ok, ok, 16).unwrap_err(),
            sky(Vec3::Y, ok, 1.0, [-1.0, 0.0, 0.0], ok, 16).unwrap_err(),
            sky(Vec3::Y, ok, 1.0, ok, [f32::INFINITY; 3], 16).unwrap_err(),
            sky(Vec3::Y, ok, 1.0, ok, ok, 12).unwrap_err(),
        ];
        let names = [
            "sun_dir",
            "sun_radiance",
            "sun_angle_deg",
            "zenith",
            "horizon",
            "resolution",
        ];
        for (e, n) in cases.iter().zip(names) {
            assert!(e.to_string().starts_with(n), "{e}");
        }
        let w = Window {
            azimuth_deg: 0.0,
            elevation_deg: 95.0,
            width_deg: 10.0,
            height_deg: 10.0,
            radiance: ok,
        };
        let e = windows(&[w, w], ok, 16).unwrap_err().to_string();
        assert!(
            e.starts_with("windows[0]") && e.contains("elevation"),
            "{e}"
        );
        let e = windows(&[], [-1.0; 3], 16).unwrap_err().to_string();
        assert!(e.starts_with("background"), "{e}");
    }
}
