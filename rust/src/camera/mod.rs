//! Pinhole camera and the G-buffer of first hits ([`GBuffer`]).
//!
//! Image convention: `(height, width)` arrays, row 0 at the top, pixel `(x, y)` covering
//! `[x, x+1) x [y, y+1)` on the film; the pixel index is `y * width + x`. The field of view
//! spans the **vertical** axis (the image height); the horizontal one follows from the
//! aspect ratio. Pixels are square.

use glam::{DVec3, Vec3, Vec3A};

use crate::error::{Error, Result};
use crate::sampling::rng::SampleRng;

mod gbuffer;
pub use gbuffer::GBuffer;

/// Largest accepted image side, in pixels.
pub const MAX_RESOLUTION: u32 = 1 << 14;

/// Random dimensions used by primary rays (dimension 0 and 1: the jitter inside the pixel).
pub const DIM_PIXEL_JITTER: u64 = 0;

/// Smallest |cos| between view ray and surface used for footprints, so grazing hits get a
/// footprint at most 10x the face-on one instead of an infinite one.
pub const FOOTPRINT_MIN_COS: f32 = 0.01;

/// A pinhole camera with an orthonormal frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Centre of projection (world units).
    pub eye: Vec3,
    /// Unit viewing direction.
    pub forward: Vec3,
    /// Unit vector toward the image's right edge.
    pub right: Vec3,
    /// Unit vector toward the image's top edge.
    pub up: Vec3,
    /// Vertical field of view in degrees, in (0, 180).
    pub fov_y_deg: f32,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

fn check_vec(name: &str, v: Vec3) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(Error::invalid(name, format!("must be finite, got {v:?}")))
    }
}

fn check_resolution(width: u32, height: u32) -> Result<()> {
    for (name, v) in [("width", width), ("height", height)] {
        if v == 0 || v > MAX_RESOLUTION {
            return Err(Error::invalid(
                name,
                format!("must be between 1 and {MAX_RESOLUTION}, got {v}"),
            ));
        }
    }
    Ok(())
}

/// The camera's orthonormal frame `(forward, right, up)` for `look_at`; where f32 cannot
/// form it, computed in f64: in f32 the length of `target - eye` overflows for an eye at 1e20 and underflows for
/// points 1e-29 apart, and a subnormal `up` has no length, though each is a valid camera.
/// Normalising first and judging after leaves only cameras that truly cannot be formed, and
/// their messages say why.
fn frame(eye: Vec3, target: Vec3, up: Vec3) -> Result<(Vec3, Vec3, Vec3)> {
    // Where the f32 frame is well defined it is the camera's, as it always was: every
    // image and cache of an ordinary camera stays bit for bit what it was.
    let forward = (target - eye).normalize_or_zero();
    let right = forward.cross(up).normalize_or_zero();
    if forward != Vec3::ZERO
        && right != Vec3::ZERO
        && forward.cross(up.normalize_or_zero()).length() >= 1e-6
    {
        return Ok((forward, right, right.cross(forward)));
    }
    let (e, t, u) = (eye.as_dvec3(), target.as_dvec3(), up.as_dvec3());
    let forward = (t - e).normalize_or_zero();
    if forward == DVec3::ZERO {
        return Err(Error::invalid(
            "target",
            format!("must differ from eye, both are {eye:?}"),
        ));
    }
    let up_unit = u.normalize_or_zero();
    if up_unit == DVec3::ZERO {
        return Err(Error::invalid("up", "must be non-zero"));
    }
    let right = forward.cross(up_unit);
    // The sine of the angle between up and the view: below 1e-6 the roll is undefined.
    if right.length() < 1e-6 {
        return Err(Error::invalid(
            "up",
            format!("must not be parallel to target - eye, got up {up:?} along {forward:?}"),
        ));
    }
    let right = right.normalize();
    let up = right.cross(forward);
    Ok((forward.as_vec3(), right.as_vec3(), up.as_vec3()))
}

impl Camera {
    /// A camera at `eye` looking at `target`, `up` fixing the roll. `fov_deg` is the
    /// vertical field of view in degrees.
    pub fn look_at(
        eye: Vec3,
        target: Vec3,
        up: Vec3,
        fov_deg: f32,
        width: u32,
        height: u32,
    ) -> Result<Self> {
        check_vec("eye", eye)?;
        check_vec("target", target)?;
        check_vec("up", up)?;
        check_resolution(width, height)?;
        if !(fov_deg > 0.0 && fov_deg < 180.0) {
            return Err(Error::invalid(
                "fov_deg",
                format!("must lie in (0, 180), got {fov_deg}"),
            ));
        }
        let (forward, right, up) = frame(eye, target, up)?;
        Ok(Self {
            eye,
            forward,
            right,
            up,
            fov_y_deg: fov_deg,
            width,
            height,
        })
    }

    /// The same view at another resolution (the vertical field of view is kept).
    pub fn with_resolution(&self, width: u32, height: u32) -> Result<Self> {
        check_resolution(width, height)?;
        Ok(Self {
            width,
            height,
            ..*self
        })
    }

    /// Number of pixels.
    pub fn num_pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Fails with [`crate::Error::OutOfMemory`] (naming `camera`) when the per-pixel
    /// buffers of a render at this resolution ([`crate::error::BYTES_PER_PIXEL`] each)
    /// cannot be allocated now.
    pub fn check_buffers(&self) -> crate::Result<()> {
        crate::error::check_memory(
            self.num_pixels()
                .saturating_mul(crate::error::BYTES_PER_PIXEL),
            "camera",
        )
    }

    fn tan_half_fov(&self) -> f32 {
        (self.fov_y_deg.to_radians() * 0.5).tan()
    }

    /// Unit direction through film position `(x, y)` in pixel units (y down).
    pub fn direction(&self, x: f32, y: f32) -> Vec3 {
        self.direction_with(self.tan_half_fov(), x, y)
    }

    /// [`Self::direction`] with `tan(fov_y / 2)` computed once by the caller: the
    /// jittered samples of a pixel share it.
    #[inline]
    fn direction_with(&self, t: f32, x: f32, y: f32) -> Vec3 {
        let (w, h) = (self.width as f32, self.height as f32);
        let sx = (2.0 * x / w - 1.0) * t * (w / h);
        let sy = (1.0 - 2.0 * y / h) * t;
        (self.forward + self.right * sx + self.up * sy).normalize()
    }

    /// Primary ray of pixel `(px, py)` through the jittered position `jitter` in [0,1)^2.
    pub fn pixel_ray(&self, px: u32, py: u32, jitter: [f32; 2]) -> (Vec3, Vec3) {
        (
            self.eye,
            self.direction(px as f32 + jitter[0], py as f32 + jitter[1]),
        )
    }

    /// Unit directions through pixel `(px, py)` at the jittered positions `jitters`
    /// (each in [0,1)^2), into `out`: [`Self::pixel_ray`]'s directions, bit for bit.
    pub fn pixel_directions(
        &self,
        px: u32,
        py: u32,
        jitters: impl IntoIterator<Item = [f32; 2]>,
        out: &mut [Vec3A],
    ) {
        let t = self.tan_half_fov();
        for (d, j) in out.iter_mut().zip(jitters) {
            *d = self
                .direction_with(t, px as f32 + j[0], py as f32 + j[1])
                .into();
        }
    }

    /// Primary ray of the pixel with row-major index `pixel`: through a position drawn from
    /// `(seed, pixel, sample 0, dimensions 0-1)` with `jitter`, else through its centre.
    pub fn primary_ray(&self, pixel: usize, seed: u64, jitter: bool) -> (Vec3, Vec3) {
        let j = if jitter {
            SampleRng::new(seed, pixel as u64, 0).get2(DIM_PIXEL_JITTER)
        } else {
            [0.5, 0.5]
        };
        let (px, py) = (pixel as u32 % self.width, pixel as u32 / self.width);
        self.pixel_ray(px, py, j)
    }

    /// Solid angle of one pixel seen along unit direction `dir` (steradians).
    pub fn pixel_solid_angle(&self, dir: Vec3) -> f32 {
        let side = 2.0 * self.tan_half_fov() / self.height as f32;
        let c = dir.dot(self.forward).max(0.0);
        side * side * c * c * c
    }

    /// Square root of the pixel's area projected onto the tangent plane (normal `normal`)
    /// of a hit at `distance` along unit `dir`. |cos| is clamped at [`FOOTPRINT_MIN_COS`].
    pub fn footprint(&self, dir: Vec3, distance: f32, normal: Vec3) -> f32 {
        let cos = dir.dot(normal).abs().max(FOOTPRINT_MIN_COS);
        (self.pixel_solid_angle(dir) / cos).sqrt() * distance
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(w: u32, h: u32) -> Camera {
        Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 45.0, w, h).unwrap()
    }

    #[test]
    fn frame_and_fov_span_the_vertical_axis() {
        let c = cam(200, 100);
        assert!((c.forward - Vec3::NEG_Z).length() < 1e-6);
        assert!((c.right - Vec3::X).length() < 1e-6 && (c.up - Vec3::Y).length() < 1e-6);
        let top = c.direction(100.0, 0.0);
        let angle = top.dot(c.forward).acos().to_degrees();
        assert!((angle - 22.5).abs() < 1e-3, "{angle}");
        let left = c.direction(0.0, 50.0);
        let expect = (2.0 * (22.5f32).to_radians().tan()).atan().to_degrees();
        assert!((left.dot(c.forward).acos().to_degrees() - expect).abs() < 1e-3);
        let small = c.with_resolution(20, 10).unwrap();
        assert!((small.direction(10.0, 0.0) - top).length() < 1e-6);
    }

    #[test]
    fn a_pixels_directions_are_its_rays_bit_for_bit() {
        let c = cam(160, 120);
        let jitters = [[0.0, 0.0], [0.999, 0.5], [0.25, 0.875], [0.5, 0.0001]];
        for (px, py) in [(0, 0), (37, 91), (159, 119)] {
            let mut out = [Vec3A::ZERO; 4];
            c.pixel_directions(px, py, jitters, &mut out);
            for (d, j) in out.iter().zip(jitters) {
                let (eye, ray) = c.pixel_ray(px, py, j);
                assert_eq!(eye, c.eye);
                assert_eq!(
                    Vec3::from(*d).to_array().map(f32::to_bits),
                    ray.to_array().map(f32::to_bits)
                );
            }
        }
    }

    #[test]
    fn pixel_solid_angles_sum_to_the_frustum() {
        // Sum over pixel centres approximates the frustum's solid angle, computed exactly
        // for a rectangle: 4 asin(sin a sin b).
        let c = cam(400, 300);
        let mut sum = 0.0f64;
        for y in 0..300 {
            for x in 0..400 {
                sum += c.pixel_solid_angle(c.direction(x as f32 + 0.5, y as f32 + 0.5)) as f64;
            }
        }
        let ty = (22.5f64).to_radians().tan();
        let (a, b) = ((ty * 4.0 / 3.0).atan(), ty.atan());
        let exact = 4.0 * (a.sin() * b.sin()).asin();
        assert!((sum / exact - 1.0).abs() < 1e-3, "{sum} vs {exact}");
    }

    #[test]
    fn bad_arguments_are_named() {
        let e = |r: Result<Camera>| r.unwrap_err().to_string();
        assert!(
            e(Camera::look_at(Vec3::ZERO, Vec3::ZERO, Vec3::Y, 45.0, 4, 4)).starts_with("target")
        );
        assert!(e(Camera::look_at(Vec3::ZERO, Vec3::Y, Vec3::Y, 45.0, 4, 4)).starts_with("up"));
        assert!(
            e(Camera::look_at(Vec3::ZERO, Vec3::X, Vec3::Y, 180.0, 4, 4)).starts_with("fov_deg")
        );
        assert!(e(Camera::look_at(Vec3::ZERO, Vec3::X, Vec3::Y, 45.0, 0, 4)).starts_with("width"));
        assert!(e(Camera::look_at(Vec3::NAN, Vec3::X, Vec3::Y, 45.0, 4, 4)).starts_with("eye"));
    }

    #[test]
    fn extreme_but_valid_cameras_are_formed() {
        // An eye far away (the length of target - eye overflows f32) or a hair's breadth
        // from the target (it underflows), and a subnormal up: each a valid camera.
        let down_z = |eye: Vec3, target: Vec3, up: Vec3| {
            let c = Camera::look_at(eye, target, up, 45.0, 4, 4).unwrap();
            assert_eq!((c.forward, c.right, c.up), (Vec3::NEG_Z, Vec3::X, Vec3::Y));
        };
        for z in [1e20, 1e30, 3.4e38, f32::MAX] {
            down_z(Vec3::new(0.0, 0.0, z), Vec3::ZERO, Vec3::Y);
            down_z(Vec3::new(0.0, 0.0, z), Vec3::new(0.0, 0.0, -z), Vec3::Y);
        }
        for gap in [1e-29, 1e-38, 1e-45] {
            down_z(Vec3::new(0.0, 0.0, gap), Vec3::ZERO, Vec3::Y);
        }
        down_z(
            Vec3::new(0.0, 0.0, 5.0),
            Vec3::ZERO,
            Vec3::new(0.0, 1e-40, 0.0),
        );
        down_z(
            Vec3::new(0.0, 0.0, 5.0),
            Vec3::ZERO,
            Vec3::new(0.0, 1e30, 0.0),
        );
    }

    #[test]
    fn impossible_cameras_say_why() {
        let e = |eye: Vec3, target: Vec3, up: Vec3| {
            Camera::look_at(eye, target, up, 45.0, 4, 4)
                .unwrap_err()
                .to_string()
        };
        let eye = Vec3::new(1.0, 2.0, 3.0);
        assert!(e(eye, eye, Vec3::Y).starts_with("target: must differ from eye"));
        assert_eq!(e(eye, Vec3::ZERO, Vec3::ZERO), "up: must be non-zero");
        let along = e(
            Vec3::ZERO,
            Vec3::new(0.0, 1e-30, 0.0),
            Vec3::new(0.0, -1e-40, 0.0),
        );
        assert!(along.starts_with("up: must not be parallel"), "{along}");
    }
}
