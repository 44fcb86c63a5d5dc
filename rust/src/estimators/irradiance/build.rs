//! The first pass of §3.2.2: records for a view, coarse to fine over its G-buffer, where no
//! record is usable (Algorithm 1, lines 3 and 7–8), grown in deterministic waves by the
//! record index's [`WaveBuilder`] — the visibility cache's and AO's build. Neighbour
//! clamping may take a point's record away after its level was walked (it lowers the
//! radii of records already made), so sweeps over every point follow until one adds
//! nothing.

use std::ops::{Deref, DerefMut};
use std::time::Instant;

use glam::Vec3;

use super::cache::{IrradianceCache, IrradianceState};
use super::record::{IrradianceRecord, RecordRays};
use crate::camera::GBuffer;
use crate::error::Result;
use crate::estimators::direct::Lighting;
use crate::geometry::TraversalCounters;
use crate::parallel::with_threads;
use crate::spatial::waves::{coarse_to_fine_levels, WaveBuilder, WaveTarget};
use crate::visibility::cache::check_scene_and_budget;

/// What a build did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct IrradianceBuildReport {
    /// Records in the cache afterwards.
    pub records: usize,
    /// Records this build inserted.
    pub inserted: usize,
    /// Records made but found unneeded on re-check (their rays are counted).
    pub discarded: usize,
    /// Pixels of the view.
    pub pixels: usize,
    /// Pixels whose first hit has a diffuse part (the points records are made for).
    pub points: usize,
    /// Hemisphere rays this build traced.
    pub hemisphere_rays: u64,
    /// Rays of the direct estimates at the hemisphere hits.
    pub secondary_rays: u64,
    /// Radii lowered by neighbour clamping during this build.
    pub clamped_radii: u64,
    /// Rounds over every point that filled the gaps neighbour clamping left.
    pub gap_rounds: u32,
    /// Wall-clock seconds.
    pub seconds: f64,
    /// False when the time budget or progress stopped the build early.
    pub complete: bool,
}

impl IrradianceCache {
    /// Grows the cache for the hits of `gbuffer` (which must describe `lighting.scene` as
    /// posed now): every pixel whose material has a diffuse part gets a usable record
    /// (module docs of [`super::cache`]). Records already held are used and kept; the
    /// result is the same for any `threads`. `progress(done, total)` (points) is called
    /// after every wave; returning false stops the build, as does `time_budget` (seconds,
    /// counted from `start`, checked between waves): the records so far are kept.
    #[allow(clippy::too_many_arguments)]
    pub fn build_from(
        &self,
        lighting: &Lighting,
        gbuffer: &GBuffer,
        seed: u64,
        threads: Option<usize>,
        start: Instant,
        time_budget: Option<f64>,
        progress: &mut (dyn FnMut(usize, usize) -> bool + Send),
    ) -> Result<IrradianceBuildReport> {
        let scene = lighting.scene;
        check_scene_and_budget(scene, time_budget)?;
        gbuffer.check(scene, None)?;
        self.bind_scene(scene)?;
        let before = self.counters();
        let objects = &scene.mesh().objects;
        // Records only where light is reflected diffusely: Phong's specular part of
        // indirect light is traced per sample.
        let diffuse = |i: usize| {
            let o = gbuffer.object[i];
            o >= 0 && diffuse_albedo(&objects[o as usize].material) != [0.0; 3]
        };
        let points: Vec<u32> = (0..gbuffer.object.len() as u32)
            .filter(|&i| diffuse(i as usize))
            .collect();
        let mut report = IrradianceBuildReport {
            pixels: gbuffer.object.len(),
            points: points.len(),
            complete: true,
            ..Default::default()
        };
        if let Some(f) = median(points.iter().map(|&i| gbuffer.footprint[i as usize])) {
            self.write().default_footprint = Some(f);
        }
        let camera = &gbuffer.camera;
        let complete = with_threads(threads, || {
            let levels = coarse_to_fine_levels(camera.width, camera.height)
                .into_iter()
                .map(|level| level.into_iter().filter(|&i| diffuse(i as usize)));
            let target = Refine {
                cache: self,
                lighting,
                gbuffer,
                seed,
            };
            let mut builder = WaveBuilder::new(start, time_budget, progress);
            let first = builder.run(&target, levels, report.points)?;
            // Clamping lowered radii under the tree's reach bounds: make them tight again.
            self.write().refresh_reach();
            report.inserted = first.inserted;
            report.discarded = first.discarded;
            let (mut complete, mut last) = (first.complete, first.inserted);
            // Neighbour clamping lowers the radii of records already placed, which may leave
            // points they served without a usable record: fill those gaps in further rounds
            // over every point (the survey's second pass, §3.2.2), until none is left.
            while complete
                && last > 0
                && self.params().clamp_neighbours
                && report.gap_rounds < MAX_GAP_ROUNDS
            {
                let all = std::iter::once(points.iter().copied());
                let round = builder.run(&target, all, report.points)?;
                self.write().refresh_reach();
                report.inserted += round.inserted;
                report.discarded += round.discarded;
                report.gap_rounds += 1;
                (complete, last) = (round.complete, round.inserted);
            }
            Ok::<_, crate::error::Error>(complete)
        })??;
        report.complete = complete;
        let after = self.counters();
        report.records = self.len();
        report.hemisphere_rays = after.hemisphere_rays - before.hemisphere_rays;
        report.secondary_rays = after.secondary_rays - before.secondary_rays;
        report.clamped_radii = after.clamped_radii - before.clamped_radii;
        report.seconds = start.elapsed().as_secs_f64();
        Ok(report)
    }
}

/// Most rounds of gap filling after the coarse-to-fine pass.
pub const MAX_GAP_ROUNDS: u32 = 8;

/// The albedo of a material's diffuse part (`kd` of Phong), per channel.
pub fn diffuse_albedo(material: &crate::bsdf::Material) -> [f32; 3] {
    match material.diffuse_lobe() {
        crate::bsdf::Material::Lambert { albedo } => albedo,
        crate::bsdf::Material::Phong { kd, .. } => kd,
    }
}

/// The median of `values` (`None` when empty or none is finite).
fn median(values: impl Iterator<Item = f32>) -> Option<f32> {
    let mut v: Vec<f32> = values.filter(|f| f.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f32::total_cmp);
    Some(*m)
}

/// The cache as [`WaveBuilder`] grows it over a G-buffer's pixels.
struct Refine<'a> {
    cache: &'a IrradianceCache,
    lighting: &'a Lighting<'a>,
    gbuffer: &'a GBuffer,
    seed: u64,
}

impl Refine<'_> {
    fn query(&self, i: u32) -> (Vec3, Vec3, f32) {
        let i = i as usize;
        let g = self.gbuffer;
        (
            Vec3::from(g.position[i]),
            Vec3::from(g.normal[i]),
            g.footprint[i],
        )
    }
}

impl WaveTarget for Refine<'_> {
    type State = IrradianceState;
    type Record = (IrradianceRecord, RecordRays, TraversalCounters);

    fn read(&self) -> impl Deref<Target = IrradianceState> + '_ {
        self.cache.read()
    }

    fn write(&self) -> impl DerefMut<Target = IrradianceState> + '_ {
        self.cache.write()
    }

    fn records(&self) -> usize {
        self.cache.len()
    }

    /// Requests within half the reach a record of `R = r_max` footprints would have wait
    /// for the next wave.
    fn point(&self, i: u32) -> (Vec3, Vec3, f32) {
        let (x, n, f) = self.query(i);
        let p = self.cache.params();
        (x, n, p.a * p.r_max * f)
    }

    /// Normals closer than the weight's normal term allows (`sqrt(1 − cos) < a`).
    fn cos_max(&self) -> f32 {
        let a = self.cache.params().a;
        1.0 - a * a
    }

    fn wants(&self, state: &IrradianceState, i: u32) -> bool {
        let (x, n, _) = self.query(i);
        let mut scratch = Vec::new();
        !state.covers(x, n, &mut scratch)
    }

    /// The record of pixel `i`, its random numbers keyed by the pixel: the same record at
    /// any scene scale, whichever wave or worker makes it.
    fn make(&self, i: u32) -> Result<Self::Record> {
        Ok(self
            .cache
            .trace(self.lighting, self.query(i), self.seed, i as u64))
    }

    fn insert(
        &self,
        state: &mut IrradianceState,
        i: u32,
        (record, rays, bvh): &Self::Record,
    ) -> Result<bool> {
        state.counters.hemisphere_rays += rays.hemisphere;
        state.counters.secondary_rays += rays.secondary;
        self.lighting.scene.add_counters(*bvh);
        if !self.wants(state, i) {
            state.counters.records_discarded += 1;
            return Ok(false);
        }
        state.push(*record, self.cache.params().clamp_neighbours)?;
        Ok(true)
    }
}

#[cfg(test)]
mod tests;
