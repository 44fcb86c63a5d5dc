//! What every pass of a render reads of the view before the first: the scene's BVH, built
//! once in parallel, and the pixels' anchors — the G-buffer of first hits through the pixel
//! centres, traced once (or handed in) and timed as the render's primary rays.

use std::time::Instant;

use crate::camera::{Camera, GBuffer};
use crate::error::Result;
use crate::geometry::Scene;
use crate::parallel::with_threads;

/// The view's anchors and what tracing them cost.
pub struct Frame<'a> {
    given: Option<&'a GBuffer>,
    traced: Option<GBuffer>,
    /// Primary rays traced for the anchors (0 when they were handed in or not needed).
    pub primary_rays: u64,
    /// CPU seconds of those rays (wall-clock seconds times the workers).
    pub primary_seconds: f64,
}

impl<'a> Frame<'a> {
    /// Builds `scene`'s BVH on `threads` workers and, when `needs_anchors` and none are
    /// `given`, traces the G-buffer through `camera`'s pixel centres.
    pub fn prepare(
        scene: &Scene,
        camera: &Camera,
        given: Option<&'a GBuffer>,
        needs_anchors: bool,
        threads: Option<usize>,
    ) -> Result<Self> {
        with_threads(threads, || {
            let _ = scene.bvh();
        })?;
        let mut frame = Self {
            given,
            traced: None,
            primary_rays: 0,
            primary_seconds: 0.0,
        };
        if given.is_none() && needs_anchors {
            let started = Instant::now();
            let (g, workers) = with_threads(threads, || {
                let g = GBuffer::render(scene, camera, 0, false, None);
                (g, rayon::current_num_threads())
            })?;
            // CPU time, as the passes' stages count it.
            let ns = started.elapsed().as_nanos() as u64 * workers as u64;
            frame.primary_seconds = ns as f64 * 1e-9;
            frame.primary_rays = camera.width as u64 * camera.height as u64;
            frame.traced = Some(g?);
        }
        Ok(frame)
    }

    /// The anchors: the given G-buffer, else the traced one, else none.
    pub fn anchors(&self) -> Option<&GBuffer> {
        self.given.or(self.traced.as_ref())
    }
}
