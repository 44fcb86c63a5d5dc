//! Lighting preview (CAM08 §6.2): the control variate's integral `J = ∫ L B~ Ṽ dω` shown
//! directly, an estimate of direct illumination from the exact lighting, the approximate
//! reflectance `B~` and the cache's interpolated visibility `Ṽ`, with no per-pixel
//! sampling.
//!
//! [`LightingPreview::new`] traces the primary rays once and keeps the first hits; every
//! [`LightingPreview::render`] after that — with another environment map, a rotated one,
//! or a cache that has grown — looks the records up again and integrates `J`, but traces
//! no ray at all (the cached transfer below traces a few toward a sun, [`edges`]).
//! Channel `c` is scaled by the material's
//! [`crate::bsdf::Material::channel_ratios`], as in the control variate.
//!
//! [`LightingPreview::render`] integrates `J` per pixel from scratch (the product's cells
//! and the records' quadtrees), which costs most of a second at 640x480. The paper names
//! the cure: cache what does not depend on the lighting. [`LightingPreview::prepare`]
//! keeps each pixel's transfer `T = B~ Ṽ` ([`transfer`]) so that
//! [`LightingPreview::render_lighting`] answers a swap, rotation or scaling of the map
//! with one projection of the map and a dot product per pixel.

pub mod bright;
mod choose;
pub mod dot;
pub mod edges;
pub mod haar;
pub mod light;
pub mod transfer;

use std::sync::{Arc, Mutex};
use std::time::Instant;

use glam::{DMat3, Vec3};
use rayon::prelude::*;

pub use choose::VisibilityErrors;
use choose::{candidates, measure, measure_visibility, probe_map};
use edges::BrightLight;
use transfer::{Basis, Transfer, TransferPoint, TransferSettings};

use super::direct::ProductLevel;
use crate::bsdf::Material;
use crate::camera::{Camera, GBuffer};
use crate::error::Result;
use crate::geometry::Scene;
use crate::lights::envmap::chroma::MapChroma;
use crate::lights::envmap::product::ProductDistribution;
use crate::lights::envmap::EnvMap;
use crate::parallel::with_threads;
use crate::stop::Stop;
use crate::visibility::cache::interpolant::{ControlTables, Interpolant};
use crate::visibility::cache::VisibilityCache;

/// A first hit kept for previews.
#[derive(Clone, Copy, Debug)]
struct PreviewPoint {
    position: Vec3,
    /// Unit normal facing the camera.
    normal: Vec3,
    /// Unit direction to the eye.
    wo: Vec3,
    /// Pixel footprint (world units); a render looks up within the cache's
    /// `d_max_scale` times it.
    footprint: f32,
    material: Material,
    /// Object id (for material edits).
    object: u32,
    /// Radiance the surface emits towards the eye (area lights).
    emitted: Vec3,
}

impl PreviewPoint {
    /// What the bright cells' light here depends on.
    fn shading(&self) -> bright::Shading {
        bright::Shading {
            normal: self.normal,
            wo: self.wo,
            material: self.material,
        }
    }
}

/// The first hits of a view, kept to preview `J` under any lighting (module docs).
#[derive(Debug)]
pub struct LightingPreview {
    width: u32,
    height: u32,
    /// Per pixel: the hit, or the primary ray's direction where it escaped.
    points: Vec<std::result::Result<PreviewPoint, Vec3>>,
    /// [`Scene::geometry_fingerprint`] of the scene the points were traced in: caches
    /// of other scenes are refused.
    scene: u64,
    /// Number of objects in the scene (material edits name one).
    objects: usize,
    /// The kept transfer, with what it was built from.
    transfer: Mutex<Option<Arc<Prepared>>>,
    /// What [`Self::render_lighting`] builds when it has no valid transfer: the last
    /// [`Self::prepare`]'s request, else [`TransferRequest::DEFAULT`].
    request: Mutex<TransferRequest>,
    /// How the last [`Self::render_lighting`] took its bright cells.
    last_bright: Mutex<Option<BrightChoice>>,
}

/// How a lighting's bright cells were added ([`LightingPreview::last_bright`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BrightChoice {
    /// Bright cells taken out of the projection.
    pub cells: usize,
    /// `Ṽ` toward them where no ray was traced from the heaviest record alone (else the
    /// cache's blend; the two differ only where a pixel's records disagree).
    pub nearest: bool,
    /// Shadow rays traced toward them where a pixel's records disagree ([`edges`]);
    /// `None` without a scene.
    pub rays: Option<u64>,
    /// Pixels that traced them.
    pub pixels: usize,
    /// When the ray budget left disagreeing pixels untraced: the two forms' errors on the
    /// traced sample, which chose `nearest` ([`edges::FormErrors`]); else the form is
    /// the one prepared.
    pub errors: Option<edges::FormErrors>,
}

impl Clone for LightingPreview {
    fn clone(&self) -> Self {
        Self {
            width: self.width,
            height: self.height,
            points: self.points.clone(),
            scene: self.scene,
            objects: self.objects,
            transfer: Mutex::new(lock(&self.transfer).clone()),
            request: Mutex::new(*lock(&self.request)),
            last_bright: Mutex::new(*lock(&self.last_bright)),
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Which basis [`LightingPreview::prepare`] keeps the transfer in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BasisChoice {
    /// The candidates that fit the budget, measured on a sample of pixels against the
    /// untruncated transfer; the cheapest to read per change among those within
    /// [`AUTO_SLACK`] of the least error wins (the whole transfer when it fits).
    Auto,
    /// The untruncated transfer (cell values at the full level): today's `J`, exactly.
    Full,
    /// Cell averages at the finest level that fits the budget.
    Texels,
    /// As many Haar terms per pixel as fit the budget.
    Haar,
    /// Spherical harmonics of the highest order that fits the budget (at most
    /// [`transfer::MAX_SH_ORDER`]).
    Sh,
}

impl BasisChoice {
    /// Parses `"auto" | "full" | "texels" | "haar"`; the error names `basis`.
    pub fn parse(s: &str) -> Result<Self> {
        Ok(match s {
            "auto" => Self::Auto,
            "full" => Self::Full,
            "texels" => Self::Texels,
            "haar" => Self::Haar,
            "sh" => Self::Sh,
            _ => {
                return Err(crate::error::Error::invalid(
                    "basis",
                    format!(
                        "must be \"auto\", \"full\", \"texels\", \"haar\" or \"sh\", got {s:?}"
                    ),
                ))
            }
        })
    }
}

/// What to build a transfer as: the basis, a memory budget and the settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TransferRequest {
    pub basis: BasisChoice,
    /// Most bytes the transfer may hold.
    pub budget_bytes: usize,
    pub settings: TransferSettings,
    /// Decide `settings.nearest` by measurement: at up to [`VISIBILITY_SAMPLE`] pixels,
    /// trace a record at the pixel (twice the cache's resolution) and compare `J` with the
    /// cache's blend of records and with the heaviest record alone against it; the
    /// lower mean error wins ([`VisibilityErrors::prefers_nearest`]). Needs the scene;
    /// without it the blend is kept. (A truncated transfer's bright cells take shadow
    /// rays where a pixel's records disagree on them, [`edges`], whatever the form.)
    pub choose_visibility: bool,
    /// Shadow rays a lighting change may trace toward the bright cells, per pixel of the
    /// view, where a pixel's records disagree on them ([`edges`]; 0: none). Finite, `>= 0`.
    pub edge_rays: f64,
}

/// Pixels a task of the view's per-pixel loops takes at least (each pixel is tens of
/// nanoseconds there).
const POINT_CHUNK: usize = 4096;

/// Pixels [`map_pixels`] fills between polls of the current [`Stop`].
const POINT_BLOCK: usize = 1 << 18;

/// `f(i)` for every pixel `i` of `0..n`, in order, in parallel, filled block by block
/// ([`POINT_BLOCK`]) into one vector. Polls the current [`Stop`] between blocks and per
/// pixel (`idle` then stands in for the block's rest): stopped, it returns
/// [`crate::Error::Interrupted`] naming `what` without touching the later blocks. (A
/// vector of 16M points is more than a gigabyte; filling all of it after a stop took 0.7 s.)
fn map_pixels<T: Send + Sync + Clone>(
    n: usize,
    what: &str,
    idle: T,
    f: impl Fn(usize) -> T + Sync,
) -> Result<Vec<T>> {
    let stop = Stop::current();
    let mut out = Vec::with_capacity(n);
    for start in (0..n).step_by(POINT_BLOCK) {
        stop.check(what)?;
        let block = start..(start + POINT_BLOCK).min(n);
        out.par_extend(block.into_par_iter().with_min_len(POINT_CHUNK).map(|i| {
            if stop.is_set() {
                idle.clone()
            } else {
                f(i)
            }
        }));
    }
    stop.check(what)?;
    Ok(out)
}

/// Pixels [`TransferRequest::choose_visibility`] traces a record at.
pub const VISIBILITY_SAMPLE: usize = 1024;

impl TransferRequest {
    /// `"auto"` within 200 MB, the renderer's product levels, interpolated `Ṽ`.
    pub const DEFAULT: Self = Self {
        basis: BasisChoice::Auto,
        budget_bytes: 200_000_000,
        settings: TransferSettings::DEFAULT,
        choose_visibility: true,
        edge_rays: EDGE_RAYS,
    };
}

/// [`TransferRequest::edge_rays`] by default: one ray per sixteen pixels, 19,200 at
/// 640x480, which keeps every suite scene's change near the 33 ms of a frame at 30 Hz
/// (`benches/README.md`, "Lighting preview").
pub const EDGE_RAYS: f64 = 1.0 / 16.0;

/// A built transfer and what it was built from.
#[derive(Clone, Debug)]
struct Prepared {
    /// [`VisibilityCache::version`] of the cache.
    cache: (u64, u64),
    request: TransferRequest,
    /// The settings built with (`nearest` decided when the request left it open).
    settings: TransferSettings,
    transfer: Transfer,
    /// Each pixel's records, for the bright cells a truncated basis leaves out
    /// ([`bright`]); `None` with the whole transfer.
    records: Option<bright::PixelRecords>,
    /// The cache's bits by direction, for the records' masks toward the bright cells;
    /// `None` with the whole transfer.
    columns: Option<bright::RecordColumns>,
    info: TransferInfo,
}

impl Prepared {
    /// Bytes the transfer, the pixels' records and the records' columns hold.
    fn bytes(&self) -> usize {
        self.transfer.memory_bytes()
            + self.records.as_ref().map_or(0, |r| r.memory_bytes())
            + self.columns.as_ref().map_or(0, |c| c.memory_bytes())
    }
}

/// What [`LightingPreview::prepare`] reports.
#[derive(Clone, Debug, PartialEq)]
pub struct TransferInfo {
    /// The basis kept.
    pub basis: Basis,
    /// The full level `L` of the transfer.
    pub level: u32,
    /// Seconds the build took (with the measurement of `"auto"`).
    pub seconds: f64,
    /// Bytes the transfer holds.
    pub bytes: usize,
    /// Pixels with a transfer.
    pub pixels: usize,
    /// `"auto"`: per candidate, its relative squared error on the sampled pixels (worst
    /// RGB channel of `Σ (J - J_full)² / Σ J_full²`), under the map measured with.
    pub measured: Vec<(Basis, f64)>,
    /// `Ṽ` from the heaviest record alone (else the cache's blend).
    pub nearest: bool,
    /// With [`TransferRequest::choose_visibility`] and a scene: the relMSE of the whole
    /// transfer's `J` against a traced record's at up to [`VISIBILITY_SAMPLE`] pixels.
    pub visibility_measured: Option<VisibilityErrors>,
}

/// Pixels [`BasisChoice::Auto`] measures on.
const AUTO_SAMPLE: usize = 1024;

/// How much more truncation error than the least [`BasisChoice::Auto`] accepts for a
/// basis that reads fewer bytes a change. Where the bases differ by this little
/// (relative squared errors of 1e-5 to 1e-3 on the suite), the preview's error is the
/// cache's and the bright cells': SH instead of Haar moved the images' relMSE by at most
/// 2% on the suite (meshes at 135°, 0.0527 to 0.0536 at 320x240). Where a basis truly
/// fits better (Haar on garage's window edges: 27x less than SH) it stays. Smaller sizes
/// of each family were tried too and dropped: measured under one map they looked as
/// good, under a sun-and-sky map SH of order 4 was up to 100x worse.
pub const AUTO_SLACK: f64 = 1.25;

impl LightingPreview {
    /// Traces one primary ray through each pixel centre of `camera` (the G-buffer's points,
    /// where a cache built for the camera has its records).
    pub fn new(scene: &Scene, camera: &Camera, threads: Option<usize>) -> Result<Self> {
        let g = GBuffer::render(scene, camera, 0, false, threads)?;
        Self::from_gbuffer(scene, &g)
    }

    /// The preview of `gbuffer`'s hits (which must describe `scene` as posed now): with the
    /// buffer a cache was built from, exactly the points its records were placed for.
    /// Stops with [`crate::Error::Interrupted`] within a pixel of the current [`Stop`]
    /// being set (per block of pixels, no later block touched; 16M pixels took 0.96 s on two
    /// cores).
    pub fn from_gbuffer(scene: &Scene, g: &GBuffer) -> Result<Self> {
        g.check(scene, None)?;
        let objects = &scene.mesh().objects;
        let points = map_pixels(g.object.len(), "LightingPreview", Err(Vec3::ZERO), |i| {
            let dir = Vec3::from(g.direction[i]);
            if g.object[i] < 0 {
                return Err(dir);
            }
            let obj = g.object[i] as u32;
            let normal = Vec3::from(g.normal[i]);
            let emitted = match scene.emitter(obj) {
                Some(light) => {
                    let first = objects[obj as usize].first_triangle;
                    let y = Vec3::from(g.position[i]);
                    light.emitted((g.prim[i] as u32 - first) as usize, y, -dir)
                }
                None => Vec3::ZERO,
            };
            Ok(PreviewPoint {
                position: Vec3::from(g.position[i]),
                normal,
                wo: -dir,
                footprint: g.footprint[i],
                material: objects[obj as usize].material,
                object: obj,
                emitted,
            })
        })?;
        Ok(Self {
            width: g.width(),
            height: g.height(),
            points,
            scene: scene.geometry_fingerprint(),
            objects: objects.len(),
            transfer: Mutex::new(None),
            request: Mutex::new(TransferRequest::DEFAULT),
            last_bright: Mutex::new(None),
        })
    }

    /// Image width and height.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// `J` per pixel (row-major RGB) under `env` with `cache`'s records, product cells of
    /// `product_level`. Escaped pixels show the map, emitters their emission,
    /// pixels without records black. Traces no rays. Stops with [`Error::Interrupted`]
    /// (`crate::Error`) within a pixel of the current [`Stop`] being set.
    pub fn render(
        &self,
        cache: &VisibilityCache,
        env: &EnvMap,
        product_level: ProductLevel,
        threads: Option<usize>,
    ) -> Result<Vec<[f32; 3]>> {
        product_level.validate()?;
        cache.bind_fingerprint(self.scene)?;
        let env = &*env.at_least(2)?;
        let chroma = MapChroma::new(env);
        let state = cache.read();
        let params = cache.params();
        let stop = Stop::current();
        let image = with_threads(threads, || {
            self.points
                .par_iter()
                .with_min_len(64)
                .map(|point| {
                    if stop.is_set() {
                        return [0.0; 3];
                    }
                    let p = match point {
                        Err(dir) => return env.eval(*dir).to_array(),
                        Ok(p) => p,
                    };
                    let lookup = state.lookup_records(
                        params,
                        p.position,
                        p.normal,
                        params.d_max_scale * p.footprint,
                    );
                    let level = product_level.for_material(&p.material);
                    let product = ProductDistribution::new(env, &p.material, p.normal, p.wo, level);
                    let j = match &product {
                        Some(product) if !lookup.neighbours().is_empty() => {
                            let tables = ControlTables::new(product, &chroma, state.store().m());
                            Interpolant::new(&state, &lookup, Some((&tables, product, env))).j
                        }
                        _ => [0.0; 3],
                    };
                    let ratios = p.material.channel_ratios();
                    std::array::from_fn(|c| p.emitted[c] + (ratios[c] as f64 * j[c]) as f32)
                })
                .collect()
        })?;
        stop.check("preview render")?;
        Ok(image)
    }
}

impl LightingPreview {
    /// The transfer inputs of every pixel (`None` where the ray escaped). Stops with
    /// [`crate::Error::Interrupted`] once the current [`Stop`] is set.
    fn transfer_points(&self, cache: &VisibilityCache) -> Result<Vec<Option<TransferPoint>>> {
        let scale = cache.params().d_max_scale;
        map_pixels(self.points.len(), "LightingPreview", None, |i| {
            self.points[i].as_ref().ok().map(|p| TransferPoint {
                position: p.position,
                normal: p.normal,
                wo: p.wo,
                radius: scale * p.footprint,
                material: p.material,
            })
        })
    }

    /// The full level of a transfer of this view's materials ([`Transfer::full_level`]),
    /// polling the current [`Stop`] between chunks of pixels.
    fn full_level(&self, cache: &VisibilityCache, settings: &TransferSettings) -> Result<u32> {
        let stop = Stop::current();
        let materials: Vec<Material> = self
            .points
            .par_chunks(POINT_CHUNK)
            .map(|chunk| {
                let mut distinct: Vec<Material> = Vec::new();
                if stop.is_set() {
                    return distinct;
                }
                for p in chunk.iter().flatten() {
                    if distinct.last() != Some(&p.material) && !distinct.contains(&p.material) {
                        distinct.push(p.material);
                    }
                }
                distinct
            })
            .flatten_iter()
            .collect();
        stop.check("LightingPreview")?;
        Transfer::full_level(cache, materials.iter(), settings)
    }

    /// Builds and keeps the transfer of `cache`'s records for this view as `request` asks
    /// (module docs); later [`Self::render_lighting`] calls reuse it while the cache is
    /// unchanged. `scene` (the scene as posed when the view was traced) lets the request
    /// choose `Ṽ`'s form by tracing a few records ([`TransferRequest::choose_visibility`]). `"auto"` measures its candidates under `env` (a sun-and-sky probe when
    /// `None` or black). Fails with an error naming `budget_mb` when no basis fits the budget.
    pub fn prepare(
        &self,
        scene: Option<&Scene>,
        cache: &VisibilityCache,
        env: Option<&EnvMap>,
        request: TransferRequest,
        threads: Option<usize>,
    ) -> Result<TransferInfo> {
        if let Some(level) = request.settings.product_level {
            level.validate()?;
        }
        if !(request.edge_rays.is_finite() && request.edge_rays >= 0.0) {
            return Err(crate::error::Error::invalid(
                "edge_rays",
                format!(
                    "must be a finite number of rays per pixel >= 0, got {}",
                    request.edge_rays
                ),
            ));
        }
        cache.bind_fingerprint(self.scene)?;
        // Every phase polls the current stop: the pixel loops per chunk, the measurements
        // per pixel, the build per pixel; between phases too.
        const WHAT: &str = "LightingPreview.prepare";
        let start = Instant::now();
        let stop = Stop::current();
        let version = cache.version();
        let points = self.transfer_points(cache)?;
        let covered = points.par_iter().filter(|p| p.is_some()).count().max(1);
        let level = self.full_level(cache, &request.settings)?;
        stop.check(WHAT)?;
        // A truncated basis also keeps each pixel's records and the records' columns
        // (for the bright cells).
        let records_bytes = bright::PixelRecords::bytes_per_pixel(cache.params());
        let columns_bytes = {
            let state = cache.read();
            bright::RecordColumns::bytes_for(state.store().len(), state.store().m())
        };
        let per_pixel = |extra: usize, fixed: usize| {
            request
                .budget_bytes
                .saturating_sub((4 + extra) * points.len() + fixed)
                / covered
        };
        let (whole, truncated) = (per_pixel(0, 0), per_pixel(records_bytes, columns_bytes));
        let candidates = candidates(level, whole, truncated, request.basis);
        if candidates.is_empty() {
            let needed = match request.basis {
                BasisChoice::Full => Basis::Texels { level }.bytes_per_pixel(),
                BasisChoice::Texels => Basis::Texels { level: 1 }.bytes_per_pixel() + records_bytes,
                _ => Basis::Haar { terms: 1 }.bytes_per_pixel() + records_bytes,
            };
            return Err(crate::error::Error::invalid(
                "budget_mb",
                format!(
                    "{:.3} MB leaves {whole} bytes for each of {covered} pixels; {} \
                     needs at least {needed}",
                    request.budget_bytes as f64 * 1e-6,
                    match request.basis {
                        BasisChoice::Full => "the whole transfer",
                        BasisChoice::Texels => "a texel basis",
                        BasisChoice::Sh => "an SH basis",
                        _ => "a transfer",
                    }
                ),
            ));
        }
        let columns = (candidates != [Basis::Texels { level }])
            .then(|| with_threads(threads, || bright::RecordColumns::of(&cache.read())))
            .transpose()?
            .transpose()?;
        let probe;
        let env = match env {
            Some(env) if !env.is_black() => env,
            _ => {
                probe = probe_map()?;
                &probe
            }
        };
        // The map as truncated bases see it: without its bright cells, which the pixels
        // add exactly.
        stop.check(WHAT)?;
        let (residual, bright) = with_threads(threads, || split_light(env, level, None, true))??;
        let split = (&residual[..], &bright);
        let mut settings = request.settings;
        let mut visibility_measured = None;
        if let (true, Some(scene)) = (request.choose_visibility, scene) {
            let errors = with_threads(threads, || {
                measure_visibility(scene, &points, cache, &settings, level, split)
            })??;
            settings.nearest = errors.prefers_nearest();
            visibility_measured = Some(errors);
        }
        stop.check(WHAT)?;
        let (basis, measured) = with_threads(threads, || {
            if candidates.len() == 1 {
                Ok((candidates[0], Vec::new()))
            } else {
                let columns = columns.as_ref().expect("several candidates are truncated");
                let masks = columns.masks(&bright, level);
                let light = (&residual[..], &bright, &masks[..]);
                measure(&points, cache, &settings, level, &candidates, env, light)
            }
        })??;
        stop.check(WHAT)?;
        let weights = transfer::level_weights(&residual);
        // The transfer is the one buffer that grows with the budget: a size that cannot be
        // allocated is an error before its work, not an abort part-way.
        crate::alloc::check_memory(basis.bytes_per_pixel().saturating_mul(covered), "budget_mb")?;
        let transfer = with_threads(threads, || {
            Transfer::build(&points, cache, settings, level, basis, Some(weights))
        })??;
        let records = (!transfer.is_whole())
            .then(|| {
                with_threads(threads, || {
                    bright::PixelRecords::gather(&points, &cache.read(), cache.params())
                })
            })
            .transpose()?
            .transpose()?;
        let columns = columns.filter(|_| !transfer.is_whole());
        let mut prepared = Prepared {
            cache: version,
            request,
            settings,
            transfer,
            records,
            columns,
            info: TransferInfo {
                basis,
                level,
                seconds: 0.0,
                bytes: 0,
                pixels: 0,
                measured,
                nearest: settings.nearest,
                visibility_measured,
            },
        };
        prepared.info.bytes = prepared.bytes();
        prepared.info.pixels = prepared.transfer.rows();
        prepared.info.seconds = start.elapsed().as_secs_f64();
        let info = prepared.info.clone();
        *lock(&self.request) = request;
        *lock(&self.transfer) = Some(Arc::new(prepared));
        Ok(info)
    }

    /// Makes later transfers use `level` for the product's cells (a kept transfer of
    /// another level is rebuilt by the next [`Self::render_lighting`]).
    pub fn set_product_level(&self, level: Option<ProductLevel>) {
        lock(&self.request).settings.product_level = level;
    }

    /// How the last [`Self::render_lighting`] added its bright cells (`None` before one,
    /// or when that lighting had none or the transfer was whole).
    pub fn last_bright(&self) -> Option<BrightChoice> {
        *lock(&self.last_bright)
    }

    /// What the kept transfer reports, if one is kept.
    pub fn transfer_info(&self) -> Option<TransferInfo> {
        lock(&self.transfer).as_ref().map(|p| p.info.clone())
    }

    /// The kept transfer when it was built from `cache` as it is now, else a new one (as
    /// the last [`Self::prepare`] asked, under `env`).
    fn prepared(
        &self,
        scene: Option<&Scene>,
        cache: &VisibilityCache,
        env: &EnvMap,
        threads: Option<usize>,
    ) -> Result<Arc<Prepared>> {
        let request = *lock(&self.request);
        if let Some(p) = lock(&self.transfer).as_ref() {
            if p.cache == cache.version() && p.request == request {
                return Ok(p.clone());
            }
        }
        self.prepare(scene, cache, Some(env), request, threads)?;
        Ok(lock(&self.transfer).clone().expect("just prepared"))
    }

    /// `J` per pixel (row-major RGB) under `env` turned by `rotation` (a feature at `ω`
    /// moves to `R ω`), from the kept transfer of `cache` — built first when there is
    /// none or the cache changed since (with `scene`, the scene as posed when the view was
    /// traced, for [`TransferRequest::choose_visibility`] and for the shadow rays toward a
    /// truncated transfer's bright cells, [`edges`], at most [`TransferRequest::edge_rays`]
    /// per pixel). Escaped pixels show the turned map, emitters their emission.
    pub fn render_lighting(
        &self,
        scene: Option<&Scene>,
        cache: &VisibilityCache,
        env: &EnvMap,
        rotation: Option<&DMat3>,
        threads: Option<usize>,
    ) -> Result<Vec<[f32; 3]>> {
        if let Some(r) = rotation {
            light::check_rotation(r)?;
        }
        cache.bind_fingerprint(self.scene)?;
        let prepared = self.prepared(scene, cache, env, threads)?;
        let transfer = &prepared.transfer;
        let (cells, mut bright) = with_threads(threads, || {
            split_light(env, transfer.level(), rotation, prepared.records.is_some())
        })??;
        let masks = match (&prepared.columns, bright.is_empty()) {
            (Some(columns), false) => {
                with_threads(threads, || columns.masks(&bright, transfer.level()))?
            }
            _ => Vec::new(),
        };
        let light = transfer.light_for(env, rotation, cells, &bright)?;
        let inverse = rotation.map(|r| r.transpose());
        // A pixel's colour from its `J`: escaped pixels show the turned map.
        let finish = |i: usize, j: [f64; 3]| -> [f32; 3] {
            match &self.points[i] {
                Err(dir) => {
                    let d = match &inverse {
                        Some(r) => (*r * dir.as_dvec3()).as_vec3(),
                        None => *dir,
                    };
                    env.eval(d).to_array()
                }
                Ok(p) => {
                    let ratios = p.material.channel_ratios();
                    std::array::from_fn(|c| p.emitted[c] + (ratios[c] as f64 * j[c]) as f32)
                }
            }
        };
        let Some(records) = prepared.records.as_ref().filter(|_| !bright.is_empty()) else {
            *lock(&self.last_bright) = None;
            let stop = Stop::current();
            let image = with_threads(threads, || {
                (0..self.points.len())
                    .into_par_iter()
                    .with_min_len(1024)
                    .map(|i| match stop.is_set() {
                        true => [0.0; 3],
                        false => finish(i, transfer.eval(i, &light)),
                    })
                    .collect()
            })?;
            stop.check("preview render")?;
            return Ok(image);
        };
        let budget = (prepared.request.edge_rays * self.points.len() as f64).round();
        // Rays only with a scene to trace in and a budget for them.
        let scene = scene.filter(|_| budget >= 1.0);
        if scene.is_some() {
            bright.aim(env, transfer.level(), rotation);
        }
        let view = edges::View {
            pixels: self.points.len(),
            point: |i: usize| match &self.points[i] {
                Ok(p) if transfer.has_row(i) => Some((p.position, p.shading())),
                _ => None,
            },
            smooth: |i: usize| transfer.eval(i, &light),
            finish,
            records,
            bright: &bright,
            masks: &masks,
        };
        let gathered = BrightLight::gather(scene, &view, budget as usize, threads)?;
        let nearest = gathered
            .judged
            .map_or(prepared.settings.nearest, |e| e.prefers_nearest());
        *lock(&self.last_bright) = Some(BrightChoice {
            cells: bright.cells.len(),
            nearest,
            rays: gathered.rays,
            pixels: gathered.traced_pixels,
            errors: gathered.judged,
        });
        gathered.image(&view, nearest, threads)
    }

    /// Gives `object` the material `material` in this view: its pixels shade with it from
    /// now on, and a kept transfer rebuilds their rows only. Returns how many pixels
    /// changed. Stopped by the current [`Stop`] ([`crate::Error::Interrupted`]), the
    /// material is set and the kept transfer dropped (the next render builds it again).
    pub fn set_material(
        &mut self,
        cache: Option<&VisibilityCache>,
        object: u32,
        material: Material,
        threads: Option<usize>,
    ) -> Result<usize> {
        if object as usize >= self.objects {
            return Err(crate::error::Error::invalid(
                "obj",
                format!("no object {object} (the scene has {})", self.objects),
            ));
        }
        let mut pixels = Vec::new();
        for (i, p) in self.points.iter_mut().enumerate() {
            if let Ok(p) = p {
                if p.object == object {
                    p.material = material;
                    pixels.push(i);
                }
            }
        }
        let mut slot = lock(&self.transfer).take();
        if let (Some(prepared), Some(cache)) = (slot.as_mut(), cache) {
            let still_valid = prepared.cache == cache.version()
                && self.full_level(cache, &prepared.settings)? == prepared.transfer.level();
            if still_valid {
                let points = self.transfer_points(cache)?;
                let p = Arc::make_mut(prepared);
                let settings = p.settings;
                // Stopped part-way, the transfer is dropped (`slot` is not put back): the
                // next render builds it again for the new material.
                with_threads(threads, || {
                    p.transfer.rebuild(&points, &pixels, cache, settings)
                })??;
                p.info.bytes = p.bytes();
                p.info.pixels = p.transfer.rows();
                *lock(&self.transfer) = slot;
            }
        }
        Ok(pixels.len())
    }
}

#[cfg(test)]
mod tests;

/// `env` turned by `rotation` as integrals over the cells of `level`, with its bright cells
/// moved out when `split` ([`bright`]; none moved otherwise, and no centroids taken).
fn split_light(
    env: &EnvMap,
    level: u32,
    rotation: Option<&DMat3>,
    split: bool,
) -> Result<(Vec<[f64; 3]>, bright::BrightCells)> {
    if !split {
        return Ok((
            light::cell_integrals(env, level, rotation)?,
            bright::BrightCells::default(),
        ));
    }
    let (mut cells, centroids) = light::cell_integrals_and_centroids(env, level, rotation)?;
    let bright = bright::BrightCells::split(&mut cells, &centroids);
    Ok((cells, bright))
}
