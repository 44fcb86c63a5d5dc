//! Method "vf" (VF, `003_66bd22f64a85d1d6.txt`): the stages of
//! [`crate::estimators::vf`] run in order on one frame, timed as the paper's Table 1
//! (voxelisation, marching, filter, illumination, upsampling), with direct light from the
//! direct methods' MIS renderer added when `direct` is set (`spp` samples per pixel), as
//! the other indirect methods add it.
//!
//! The three G-buffers (marching, indirect, camera resolution) trace pixel centres, so
//! the indirect image is a point sample per pixel (the references are box-filtered); the
//! direct part is antialiased as `jitter` says. A `time_budget` bounds the direct part
//! only (VF's own work is one fixed pass): where the frame alone overruns it,
//! `first_sample_seconds` says when the image had its indirect light and every pixel a
//! direct sample. Ctrl-C and a `false` from progress (called
//! between stages, `(stage, 7)`) stop the render with [`Error::Interrupted`].

use std::time::Instant;

use super::output::{RenderOutput, Stats, View};
use super::registry::{MethodInputs, MethodRenderer, MethodSpec};
use super::{render, RenderParams};
use crate::camera::{Camera, GBuffer};
use crate::error::{Error, Result};
use crate::estimators::direct::{Lighting, Method};
use crate::estimators::vf::filter::filter;
use crate::estimators::vf::gather::{gather, GatherCounts, LowRes};
use crate::estimators::vf::march::{march, Lists};
use crate::estimators::vf::proxy_grid::ProxyGrid;
use crate::estimators::vf::upsample::upsample;
use crate::estimators::vf::{surfels, VfParams, DEFAULT_MERGE_VOXELS, DEFAULT_SH_RANGE_SHARE};
use crate::geometry::Scene;
use crate::lights::envmap::EnvMap;
use crate::parallel::with_threads;
use crate::stop::Stop;

/// Figures of one VF frame (seconds are wall-clock).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VfStats {
    /// The whole call.
    pub seconds: f64,
    /// Placing and lighting the proxies (the paper's light-view rasterisation).
    pub proxy_seconds: f64,
    /// Table 1's rows.
    pub voxelisation_seconds: f64,
    pub marching_seconds: f64,
    pub filter_seconds: f64,
    pub illumination_seconds: f64,
    pub upsampling_seconds: f64,
    /// Tracing the three G-buffers.
    pub gbuffer_seconds: f64,
    /// The direct part (zero without `direct`).
    pub direct_seconds: f64,
    pub proxies: u64,
    /// VPLs (lit proxy sides).
    pub vpls: u64,
    /// Voxels holding a disc, and holding a VPL.
    pub occupied_voxels: u64,
    pub lit_voxels: u64,
    /// Mean list length over the marching pixels that saw a surface, before and after
    /// the filter.
    pub mean_list_before: f64,
    pub mean_list_after: f64,
    /// Marching rays cast.
    pub marching_rays: u64,
    pub gather: GatherCounts,
    /// `R` used (world units).
    pub sh_range: f32,
    /// The merge range used (world units).
    pub merge_range: f32,
    /// Whether the grids used the hashed table.
    pub hashed: bool,
    /// The marching and indirect sizes used.
    pub marching: [u32; 2],
    pub indirect: [u32; 2],
    /// Under a time budget the frame overran: seconds from the call until the image had
    /// its indirect light and every pixel a direct sample (VF's frame is one step a
    /// budget cannot divide).
    pub first_sample_seconds: Option<f64>,
    /// The direct part's least samples per pixel and passes (0 without `direct`), and
    /// whether it finished them (true without `direct`).
    pub spp: u32,
    pub passes: u32,
    pub complete: bool,
}

/// The indirect image at the camera's resolution and the figures of the indirect stages.
pub struct VfFrame {
    pub image: Vec<[f32; 3]>,
    pub stats: VfStats,
}

/// `R` of eq. 6 for `params` in `scene`: the given one, else
/// [`DEFAULT_SH_RANGE_SHARE`] of the scene's diagonal.
pub fn sh_range(params: &VfParams, scene: &Scene) -> f32 {
    params.sh_range.unwrap_or_else(|| {
        let b = scene.bounds();
        DEFAULT_SH_RANGE_SHARE * (b.max - b.min).length()
    })
}

/// Mean list length over pixels that saw a surface.
fn mean_length(lists: &Lists, g: &GBuffer) -> f64 {
    let hit: Vec<usize> = (0..g.len()).filter(|&i| g.object[i] >= 0).collect();
    if hit.is_empty() {
        return 0.0;
    }
    hit.iter().map(|&i| lists.get(i).len()).sum::<usize>() as f64 / hit.len() as f64
}

/// The indirect light of `camera`'s view by VF with a given [`ProxyGrid`] (built for
/// `scene`, else an error naming `grid`). Runs on the calling pool.
pub fn vf_frame(
    scene: &Scene,
    grid: &ProxyGrid,
    camera: &Camera,
    params: &VfParams,
    seed: u64,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
) -> Result<VfFrame> {
    params.validate([camera.width, camera.height])?;
    if grid.vpls.fingerprint != scene.geometry_fingerprint() {
        return Err(Error::invalid(
            "grid",
            "was built for other geometry: build it again for this scene",
        ));
    }
    let stop = Stop::current();
    let mut step = |k: u64| -> Result<()> {
        stop.check("vf")?;
        if progress(k, 7) {
            Ok(())
        } else {
            Err(Error::Interrupted {
                what: "vf".to_string(),
            })
        }
    };
    let start = Instant::now();
    let r = sh_range(params, scene);
    let merge_range = params
        .merge_range
        .unwrap_or(DEFAULT_MERGE_VOXELS * grid.frame().cell.length());
    let (ind_size, low_size) = params.sizes([camera.width, camera.height]);
    let low_cam = camera.with_resolution(low_size[0], low_size[1])?;
    let ind_cam = camera.with_resolution(ind_size[0], ind_size[1])?;
    let low = GBuffer::render(scene, &low_cam, seed, false, None)?;
    let ind = GBuffer::render(scene, &ind_cam, seed, false, None)?;
    let full = GBuffer::render(scene, camera, seed, false, None)?;
    let gbuffer_seconds = start.elapsed().as_secs_f64();
    step(2)?;
    let t = Instant::now();
    let lists = march(
        scene,
        &low,
        &grid.disc_index,
        &grid.discs,
        &grid.home,
        params.rays_per_pixel,
        seed,
    )?;
    let marching_seconds = t.elapsed().as_secs_f64();
    step(3)?;
    let low_surfels = surfels(&low);
    let (lw, lh) = (low.width() as usize, low.height() as usize);
    let t = Instant::now();
    let filtered = filter(
        &lists,
        &low_surfels,
        lw,
        lh,
        params.filter,
        params.depth_tol,
        params.normal_tol,
    )?;
    let filter_seconds = t.elapsed().as_secs_f64();
    step(4)?;
    let t = Instant::now();
    let (indirect, counts) = gather(
        scene,
        &ind,
        LowRes {
            lists: &filtered,
            surfels: &low_surfels,
            width: lw,
            height: lh,
        },
        &grid.lights,
        r,
        merge_range,
        params.specular_sigma,
        params.depth_tol,
        params.normal_tol,
        params.visibility,
    )?;
    let illumination_seconds = t.elapsed().as_secs_f64();
    step(5)?;
    let t = Instant::now();
    let image = upsample(
        &indirect,
        &surfels(&ind),
        ind.width() as usize,
        ind.height() as usize,
        &surfels(&full),
        full.width() as usize,
        full.height() as usize,
        params.depth_tol,
        params.normal_tol,
    )?;
    let upsampling_seconds = t.elapsed().as_secs_f64();
    step(6)?;
    let marching_rays = (0..low.len()).filter(|&i| low.object[i] >= 0).count() as u64
        * params.rays_per_pixel as u64;
    Ok(VfFrame {
        image,
        stats: VfStats {
            seconds: start.elapsed().as_secs_f64(),
            proxy_seconds: grid.proxy_seconds,
            voxelisation_seconds: grid.voxel_seconds,
            marching_seconds,
            filter_seconds,
            illumination_seconds,
            upsampling_seconds,
            gbuffer_seconds,
            direct_seconds: 0.0,
            proxies: grid.proxies.len() as u64,
            vpls: grid.vpls.len() as u64,
            occupied_voxels: grid.occupied_voxels() as u64,
            lit_voxels: grid.lit_voxels() as u64,
            mean_list_before: mean_length(&lists, &low),
            mean_list_after: mean_length(&filtered, &low),
            marching_rays,
            gather: counts,
            sh_range: r,
            merge_range,
            hashed: grid.disc_index.is_hashed(),
            marching: low_size,
            indirect: ind_size,
            first_sample_seconds: None,
            spp: 0,
            passes: 0,
            complete: true,
        },
    })
}

/// A whole VF render: the grid (`grid`, built for `scene` and lit by `env`, else built
/// here from `params` and `seed`: the same grid [`ProxyGrid::build`] makes with that seed),
/// the frame, and with `direct` the direct light of `direct_params` (MIS, no bounce)
/// added. Runs on `threads` workers. A given grid's build is not in `seconds`; its
/// `voxelisation_seconds` are the build's.
#[allow(clippy::too_many_arguments)]
pub fn render_vf(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    params: &VfParams,
    seed: u64,
    direct: Option<RenderParams>,
    grid: Option<&ProxyGrid>,
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
) -> Result<RenderOutput<VfStats>> {
    params.validate([camera.width, camera.height])?;
    camera.check_buffers()?;
    let start = Instant::now();
    let env2 = env.at_least(2)?;
    let lighting = Lighting {
        scene,
        env: &env2,
        product_level: RenderParams::DEFAULT.product_level,
    };
    let frame = with_threads(threads, || -> Result<VfFrame> {
        let _ = scene.bvh();
        let built;
        let grid = match grid {
            Some(g) => g,
            None => {
                built = ProxyGrid::build(
                    &lighting,
                    params.proxies,
                    params.voxels,
                    params.table_slots,
                    seed,
                    None,
                )?;
                &built
            }
        };
        if !progress(1, 7) {
            return Err(Error::Interrupted {
                what: "vf".to_string(),
            });
        }
        vf_frame(scene, grid, camera, params, seed, progress)
    })??;
    let mut stats = frame.stats;
    let mut image = frame.image;
    let n = image.len();
    let (mut variance, mut counts) = (vec![[0.0f32; 3]; n], vec![1u32; n]);
    let frame_end = start.elapsed().as_secs_f64();
    let overran = direct
        .and_then(|d| d.time_budget)
        .is_some_and(|b| frame_end > b);
    if overran {
        stats.first_sample_seconds = Some(frame_end);
    }
    if let Some(dp) = direct {
        let t = Instant::now();
        let dp = RenderParams {
            method: Method::Mis,
            bounces: 0,
            direct: true,
            time_budget: dp
                .time_budget
                .map(|b| (b - start.elapsed().as_secs_f64()).max(1e-3)),
            ..dp
        };
        let d = render(scene, env, camera, &dp, None, threads, progress)?;
        for (px, dpx) in image.iter_mut().zip(&d.image) {
            for c in 0..3 {
                px[c] += dpx[c];
            }
        }
        variance = d.variance;
        counts = d.sample_counts;
        stats.spp = d.stats.spp;
        stats.passes = d.stats.passes;
        stats.complete = d.stats.complete;
        if let Some(f) = d.stats.first_sample_seconds {
            stats.first_sample_seconds = Some(frame_end + f);
        } else if overran {
            stats.first_sample_seconds = Some(start.elapsed().as_secs_f64());
        }
        stats.direct_seconds = t.elapsed().as_secs_f64();
    }
    stats.seconds = start.elapsed().as_secs_f64();
    Ok(RenderOutput {
        width: camera.width,
        height: camera.height,
        image,
        variance,
        alpha: None,
        sample_counts: counts,
        stats,
    })
}

/// The registry's renderer of method "vf".
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VfRenderer;

impl VfRenderer {
    /// Renders `inputs` with row `spec` (method "vf") from a grid built beforehand
    /// (`grid`: Python's `proxies=vc.vf.ProxyGrid(...)`; `None`: built for the render from
    /// `inputs.vf`). The grid must be `inputs.scene`'s, else an error naming `proxies`.
    pub fn render_with(
        &self,
        spec: &MethodSpec,
        inputs: &MethodInputs<'_>,
        grid: Option<&ProxyGrid>,
        progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
    ) -> Result<RenderOutput> {
        if spec.renderer.family() != "vf" {
            return Err(Error::invalid(
                "proxies",
                format!(
                    "a ProxyGrid is for method \"vf\", got method {:?}",
                    spec.name
                ),
            ));
        }
        if inputs.cache.is_some() {
            return Err(Error::invalid("cache", "method \"vf\" takes no cache"));
        }
        if let Some(g) = grid {
            if g.vpls.fingerprint != inputs.scene.geometry_fingerprint() {
                return Err(Error::invalid(
                    "proxies",
                    "the ProxyGrid was built for other geometry: build it again for this \
                     scene",
                ));
            }
        }
        let View::Camera(camera) = inputs.view else {
            return Err(Error::invalid(
                "gbuffer",
                "method \"vf\" traces its own G-buffers at three resolutions",
            ));
        };
        let bounces = inputs.bounces_for(spec)?;
        if bounces != 1 {
            return Err(Error::invalid(
                "bounces",
                format!("VF computes one bounce of light: bounces must be 1, got {bounces}"),
            ));
        }
        let params = inputs.vf.unwrap_or_default();
        let p = &inputs.params;
        let direct = p.direct.then(|| RenderParams {
            spp: inputs.spp_for(spec),
            ..*p
        });
        if let Some(d) = &direct {
            d.validate()?;
        }
        let out = render_vf(
            inputs.scene,
            inputs.env,
            camera,
            &params,
            p.seed,
            direct,
            grid,
            inputs.threads,
            progress,
        )?;
        Ok(out.map_stats(|s| {
            let mut d = Stats::default();
            d.set("method", spec.name);
            d.set("bounces", 1u32);
            d.set("direct", p.direct);
            d.set("seconds", s.seconds);
            d.set("spp", s.spp);
            d.set("passes", s.passes);
            d.set("complete", s.complete);
            d.set("proxy_seconds", s.proxy_seconds);
            d.set("voxelisation_seconds", s.voxelisation_seconds);
            d.set("marching_seconds", s.marching_seconds);
            d.set("filter_seconds", s.filter_seconds);
            d.set("illumination_seconds", s.illumination_seconds);
            d.set("upsampling_seconds", s.upsampling_seconds);
            d.set("gbuffer_seconds", s.gbuffer_seconds);
            d.set("direct_seconds", s.direct_seconds);
            d.set("proxies", s.proxies);
            d.set("vpls", s.vpls);
            d.set("occupied_voxels", s.occupied_voxels);
            d.set("nonempty_voxels", s.lit_voxels);
            d.set("mean_list_before", s.mean_list_before);
            d.set("mean_list_after", s.mean_list_after);
            d.set("marching_rays", s.marching_rays);
            d.set("vpl_terms", s.gather.vpl_terms);
            d.set("sh_terms", s.gather.sh_terms);
            d.set("culled_voxels", s.gather.culled_voxels);
            d.set("sh_range", s.sh_range);
            d.set("merge_range", s.merge_range);
            d.set("hashed", s.hashed);
            d.set("first_sample_seconds", s.first_sample_seconds);
            d.set(
                "voxels",
                grid.map_or(params.voxels, |g| g.frame().dims)
                    .map(u64::from)
                    .to_vec(),
            );
            d.set("marching", s.marching.map(u64::from).to_vec());
            d.set("indirect", s.indirect.map(u64::from).to_vec());
            d.set("rays_per_pixel", params.rays_per_pixel);
            d.set("filter", params.filter);
            d.set("grid_given", grid.is_some());
            d
        }))
    }
}

impl MethodRenderer for VfRenderer {
    fn family(&self) -> &'static str {
        "vf"
    }

    fn render(
        &self,
        spec: &MethodSpec,
        inputs: &MethodInputs<'_>,
        progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
    ) -> Result<RenderOutput> {
        self.render_with(spec, inputs, None, progress)
    }
}

#[cfg(test)]
mod tests;
