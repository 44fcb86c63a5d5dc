//! Algorithm 12's records for a view: candidates on the non-specular camera-visible points
//! of a G-buffer — a grid every `spacing` pixels, then every other point that has fewer
//! than `nearest` records within reach — grown in deterministic waves by the record
//! index's [`WaveBuilder`] (the irradiance and visibility caches' build), so the records
//! are the same for any thread count.

use std::ops::{Deref, DerefMut};
use std::time::Instant;

use glam::Vec3;

use super::bound::Region;
use super::records::{
    b_value, ImportanceCache, ImportanceRecord, ImportanceState, RowCdf, REACH, REGION_CONE,
};
use crate::camera::GBuffer;
use crate::error::Result;
use crate::estimators::direct::ShadingPoint;
use crate::estimators::irradiance::build::diffuse_albedo;
use crate::estimators::many_lights::light_paths::Receiver;
use crate::geometry::{RayBatch, Scene, TMax};
use crate::lights::vpl::luminance;
use crate::parallel::with_threads;
use crate::spatial::waves::{WaveBuilder, WaveTarget};

/// What a build did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImportanceBuildReport {
    /// Records in the cache afterwards.
    pub records: usize,
    /// Records this build inserted.
    pub inserted: usize,
    /// Records made but found unneeded on re-check.
    pub discarded: usize,
    /// Records inserted on the grid.
    pub grid: usize,
    /// Pixels of the view.
    pub pixels: usize,
    /// Pixels whose first hit has a diffuse part (the candidates).
    pub points: usize,
    /// Record-light pairs evaluated (records made times lights).
    pub pairs: u64,
    /// Shadow rays traced (pairs with a zero term take none).
    pub rays: u64,
    /// Wall-clock seconds.
    pub seconds: f64,
    /// False when the time budget or progress stopped the build early.
    pub complete: bool,
}

impl ImportanceCache {
    /// Grows the cache for the hits of `gbuffer` (which must describe `scene`, the scene
    /// the lights were traced in): records on the grid, then where a point has fewer than
    /// `nearest` within reach (module docs). Records held already count. `progress(done,
    /// total)` (points) is called after every wave; false stops the build, as does
    /// `time_budget` (seconds from `start`): the records so far are kept.
    pub fn build_from(
        &self,
        scene: &Scene,
        gbuffer: &GBuffer,
        threads: Option<usize>,
        start: Instant,
        time_budget: Option<f64>,
        progress: &mut (dyn FnMut(usize, usize) -> bool + Send),
    ) -> Result<ImportanceBuildReport> {
        crate::visibility::cache::check_scene_and_budget(scene, time_budget)?;
        self.check_scene(scene)?;
        gbuffer.check(scene, None)?;
        let objects = &scene.mesh().objects;
        let diffuse = |i: usize| {
            let o = gbuffer.object[i];
            o >= 0 && diffuse_albedo(&objects[o as usize].material) != [0.0; 3]
        };
        let points: Vec<u32> = (0..gbuffer.object.len() as u32)
            .filter(|&i| diffuse(i as usize))
            .collect();
        let (w, s) = (gbuffer.camera.width, self.params().spacing);
        let on_grid = |i: u32| (i % w).is_multiple_of(s) && (i / w).is_multiple_of(s);
        let mut report = ImportanceBuildReport {
            pixels: gbuffer.object.len(),
            points: points.len(),
            complete: true,
            ..Default::default()
        };
        let target = Grow {
            cache: self,
            scene,
            gbuffer,
            spacing: s as f32,
            on_grid: &on_grid,
            counts: std::sync::Mutex::new((0, 0, 0)),
        };
        let complete = with_threads(threads, || {
            let _ = scene.bvh();
            let grid: Vec<u32> = points.iter().copied().filter(|&i| on_grid(i)).collect();
            let rest: Vec<u32> = points.iter().copied().filter(|&i| !on_grid(i)).collect();
            let mut builder = WaveBuilder::new(start, time_budget, progress);
            let run = builder.run(&target, [grid, rest], report.points)?;
            report.inserted = run.inserted;
            report.discarded = run.discarded;
            Ok::<_, crate::error::Error>(run.complete)
        })??;
        let (pairs, rays, grid) = *target.counts.lock().unwrap_or_else(|e| e.into_inner());
        report.complete = complete;
        report.records = self.len();
        report.pairs = pairs;
        report.rays = rays;
        report.grid = grid;
        report.seconds = start.elapsed().as_secs_f64();
        Ok(report)
    }

    /// The record of the surface point `position` (unit `normal` on the viewer's side `wo`)
    /// of diffuse albedo `albedo`, reaching `radius`: every light's F, U and B (module docs
    /// of [`super::records`]). Also the shadow rays traced. Takes no lock.
    pub fn make_record(
        &self,
        scene: &Scene,
        (position, normal, wo): (Vec3, Vec3, Vec3),
        albedo: [f32; 3],
        radius: f32,
    ) -> Result<(ImportanceRecord, u64)> {
        let lights = &self.lights;
        let n = lights.len();
        let f_s = Vec3::from(albedo) * std::f32::consts::FRAC_1_PI;
        let sp = ShadingPoint {
            origin: scene.offset_point(position, normal),
            normal,
            wo,
            material: crate::bsdf::Material::Lambert { albedo },
        };
        let receiver = Receiver::new(scene, sp);
        let region = Region {
            position,
            normal,
            radius,
            cone: REGION_CONE,
        };
        let mut u = vec![0.0f64; n];
        let mut b = vec![0.0f64; n];
        let (mut origins, mut directions, mut tmax, mut owner) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (k, v) in lights.iter().enumerate() {
            if v.kind.is_area() {
                // A whole area light: U is its quadrature over fixed points (positive
                // wherever it can reach the record), F that times the visibility of its
                // centroid: a shape for the pdf, never a claim of the light's value.
                u[k] = luminance(v.unoccluded(scene, &receiver, None, self.disk_area)) as f64;
                let d = v.origin - sp.origin;
                let dist = d.length();
                let t = dist - 2.0 * scene.ray_epsilon(v.origin);
                if u[k] > 0.0 && t > 0.0 {
                    origins.push(sp.origin.to_array());
                    directions.push((d / dist).to_array());
                    tmax.push(t);
                    owner.push(k as u32);
                }
            } else if let Some(c) = v.connect(&receiver, None, self.disk_area) {
                u[k] = luminance(c.value) as f64;
                // From the record towards the light: the record's rays share one origin.
                let (dir, t) = if v.kind == crate::lights::vpl::VplKind::Env {
                    (c.direction, c.tmax)
                } else {
                    let d = v.origin - sp.origin;
                    let dist = d.length();
                    (d / dist, dist - 2.0 * scene.ray_epsilon(v.origin))
                };
                if t > 0.0 && u[k] > 0.0 {
                    origins.push(sp.origin.to_array());
                    directions.push(dir.to_array());
                    tmax.push(t);
                    owner.push(k as u32);
                }
            }
            b[k] = b_value(v, &region, f_s, self.disk_area, u[k]);
        }
        let occluded = scene.occluded(
            &RayBatch {
                origins: &origins,
                directions: &directions,
                tmax: TMax::PerRay(&tmax),
            },
            None,
        )?;
        let mut f = vec![0.0f64; n];
        for (&k, o) in owner.iter().zip(&occluded) {
            if !o {
                f[k as usize] = u[k as usize];
            }
        }
        Ok((
            ImportanceRecord {
                position,
                normal,
                radius,
                rows: [&f, &u, &b].map(|values| RowCdf::from_values(values)),
            },
            occluded.len() as u64,
        ))
    }
}

/// Records of `state` whose reach covers `x` with a normal within [`REGION_CONE`] of `n`,
/// and whether one lies within `near` of `x` (with such a normal).
fn in_reach(state: &ImportanceState, x: Vec3, n: Vec3, near: f32) -> (usize, bool) {
    let mut found = Vec::new();
    state.index.within_reach(x, &mut found);
    let cos = REGION_CONE.cos();
    let mut count = 0;
    let mut close = false;
    for (id, d2) in found {
        if state.index.site(id as usize).1.dot(n) >= cos {
            count += 1;
            close |= d2 < near * near;
        }
    }
    (count, close)
}

/// The cache as [`WaveBuilder`] grows it over a G-buffer's pixels.
struct Grow<'a> {
    cache: &'a ImportanceCache,
    scene: &'a Scene,
    gbuffer: &'a GBuffer,
    spacing: f32,
    on_grid: &'a (dyn Fn(u32) -> bool + Sync),
    /// Pairs, rays, grid records inserted.
    counts: std::sync::Mutex<(u64, u64, usize)>,
}

impl Grow<'_> {
    /// Position, normal and footprint of pixel `i`.
    fn query(&self, i: u32) -> (Vec3, Vec3, f32) {
        let (g, i) = (self.gbuffer, i as usize);
        (
            Vec3::from(g.position[i]),
            Vec3::from(g.normal[i]),
            g.footprint[i],
        )
    }

    fn reach(&self, footprint: f32) -> f32 {
        REACH * self.spacing * footprint
    }
}

impl WaveTarget for Grow<'_> {
    type State = ImportanceState;
    type Record = (ImportanceRecord, u64);

    fn read(&self) -> impl Deref<Target = ImportanceState> + '_ {
        self.cache.read()
    }

    fn write(&self) -> impl DerefMut<Target = ImportanceState> + '_ {
        self.cache.write()
    }

    fn records(&self) -> usize {
        self.cache.len()
    }

    /// Grid requests defer only what lies within half a spacing; the rest within half a
    /// reach.
    fn point(&self, i: u32) -> (Vec3, Vec3, f32) {
        let (x, n, f) = self.query(i);
        let d = if (self.on_grid)(i) {
            self.spacing * f
        } else {
            self.reach(f)
        };
        (x, n, d)
    }

    fn cos_max(&self) -> f32 {
        REGION_CONE.cos()
    }

    /// A grid point wants a record unless one lies within half a spacing (a second build
    /// of the same view adds none); any other point when fewer than `nearest` reach it.
    fn wants(&self, state: &ImportanceState, i: u32) -> bool {
        let (x, n, f) = self.query(i);
        let (count, close) = in_reach(state, x, n, 0.5 * self.spacing * f);
        if (self.on_grid)(i) {
            !close
        } else {
            count < self.cache.params().nearest as usize
        }
    }

    fn make(&self, i: u32) -> Result<Self::Record> {
        let (x, n, f) = self.query(i);
        let g = self.gbuffer;
        let wo = -Vec3::from(g.direction[i as usize]);
        let o = g.object[i as usize] as usize;
        let albedo = diffuse_albedo(&self.scene.mesh().objects[o].material);
        self.cache
            .make_record(self.scene, (x, n, wo), albedo, self.reach(f).max(1e-30))
    }

    fn insert(&self, state: &mut ImportanceState, i: u32, record: &Self::Record) -> Result<bool> {
        {
            let mut c = self.counts.lock().unwrap_or_else(|e| e.into_inner());
            c.0 += self.cache.lights.len() as u64;
            c.1 += record.1;
        }
        if !self.wants(state, i) {
            return Ok(false);
        }
        let r = record.0.clone();
        let radius = r.radius;
        state.index.admit(|set| {
            set.records.push(r);
            Ok(set.records.len() - 1)
        })?;
        state.max_radius = state.max_radius.max(radius);
        if (self.on_grid)(i) {
            self.counts.lock().unwrap_or_else(|e| e.into_inner()).2 += 1;
        }
        Ok(true)
    }
}
