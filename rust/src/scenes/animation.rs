//! Animated setups: one object of the scene follows a deterministic path, a pure function
//! of the integer frame index, so any frame can be reached directly and frame `i` then
//! frame `j` gives bit for bit the triangles of frame `j` alone.
//!
//! Moving goes through [`Scene::set_object_transform`] (rest pose times the frame's
//! transform) with a BVH refit. The tree is always the one built at the rest pose (frame 0
//! when the path starts there), with the moving object in a subtree of its own, refit to
//! the frame: [`Animation::apply`] builds it if the scene has none yet. So node visits and
//! closest-hit ties at a frame do not depend on the frames visited before (unless the
//! scene is rebuilt by hand at another frame).

use std::f64::consts::TAU;

use glam::{Affine3A, DVec3, Quat, Vec3};

use crate::error::{Error, Result};
use crate::geometry::{Bounds, Scene};

/// The motion of an animated object, as a function of the frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Motion {
    /// A ball of radius `radius` whose centre is `center` at rest rolls without slipping
    /// along the horizontal unit vector `direction` to `distance` away and back, once every
    /// `period` frames: at frame `f` it has travelled
    /// `s = distance * (1 - cos(2 pi f / period)) / 2` and turned `s / radius` radians about
    /// `+y x direction`. Frame 0 (and every multiple of `period`) is the rest pose.
    Roll {
        center: Vec3,
        radius: f32,
        direction: Vec3,
        distance: f32,
        period: u64,
    },
}

/// One moving object: object id in the setup's scene and its motion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Animation {
    pub object: u32,
    pub motion: Motion,
}

impl Animation {
    /// Frames after which the motion repeats.
    pub fn period(&self) -> u64 {
        match self.motion {
            Motion::Roll { period, .. } => period,
        }
    }

    /// The transform of the object at `frame`, relative to its rest pose. Computed in
    /// `f64` from `frame % period`, so it is exact to `f32` for any frame.
    pub fn transform(&self, frame: u64) -> Affine3A {
        match self.motion {
            Motion::Roll {
                center,
                radius,
                direction,
                distance,
                period,
            } => {
                let phase = (frame % period) as f64 / period as f64;
                let s = distance as f64 * 0.5 * (1.0 - (TAU * phase).cos());
                let d = direction.as_dvec3();
                let axis = DVec3::Y.cross(d).normalize();
                let angle = s / radius as f64;
                let rotation = Quat::from_axis_angle(axis.as_vec3(), angle as f32);
                let c = center.as_dvec3();
                let moved = (c + d * s).as_vec3();
                // x -> R (x - c) + c + s d
                Affine3A::from_translation(moved)
                    * Affine3A::from_quat(rotation)
                    * Affine3A::from_translation(-center)
            }
        }
    }

    /// Moves the object of `scene` to `frame` and refits the BVH. The first time (or when
    /// the scene has no BVH) the tree is built at the rest pose with the object in a
    /// subtree of its own (see [`Scene::set_object_transform_with`]). Fails, leaving the
    /// scene unchanged, when the scene has no such object.
    pub fn apply(&self, scene: &mut Scene, frame: u64) -> Result<()> {
        if !scene.is_built() || !scene.is_posed(self.object) {
            scene.set_object_transform(self.object, Affine3A::IDENTITY)?;
            scene.bvh();
        }
        scene.set_object_transform(self.object, self.transform(frame))
    }

    /// Bounds of the moving object in `scene` as it is now.
    pub fn bounds(&self, scene: &Scene) -> Result<Bounds> {
        scene.object_bounds(self.object)
    }
}

/// `frame` for a setup without animation: only 0 is accepted.
pub(crate) fn static_frame(name: &str, frame: u64) -> Result<()> {
    if frame == 0 {
        Ok(())
    } else {
        Err(Error::invalid(
            "frame",
            format!("setup {name:?} is not animated: only frame 0 exists, got {frame}"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn roll() -> Animation {
        Animation {
            object: 0,
            motion: Motion::Roll {
                center: Vec3::new(0.2, 0.8, 0.6),
                radius: 0.8,
                direction: Vec3::new(-1.0, 0.0, 1.0).normalize(),
                distance: 2.0,
                period: 60,
            },
        }
    }

    #[test]
    fn rolls_without_slipping_and_repeats() {
        let a = roll();
        assert_eq!(a.transform(0), Affine3A::IDENTITY);
        assert_eq!(a.transform(60), a.transform(0));
        assert_eq!(a.transform(7), a.transform(7 + 60 * 1000));
        assert_eq!(a.transform(u64::MAX), a.transform(u64::MAX % 60));
        let Motion::Roll {
            center,
            radius,
            direction,
            distance,
            ..
        } = a.motion;
        // Half way: the centre is `distance` along, the contact point is still under it.
        let t = a.transform(30);
        let c = t.transform_point3(center);
        assert!((c - (center + direction * distance)).length() < 1e-5, "{c}");
        // Rolling: the point that touched the ground at rest has turned by s / r.
        let bottom = t.transform_point3(center - Vec3::Y * radius);
        let angle = (bottom - c).angle_between(-Vec3::Y);
        assert!((angle - distance / radius).abs() < 1e-4, "{angle}");
        // Rolling forward, the old contact point turns up the back of the ball.
        let t = a.transform(1);
        let c = t.transform_point3(center);
        let bottom = t.transform_point3(center - Vec3::Y * radius);
        assert!((bottom - c).dot(direction) < 0.0);
    }

    #[test]
    fn static_frames() {
        assert!(static_frame("garage", 0).is_ok());
        let e = static_frame("garage", 3).unwrap_err().to_string();
        assert!(e.starts_with("frame") && e.contains("garage"), "{e}");
    }
}
