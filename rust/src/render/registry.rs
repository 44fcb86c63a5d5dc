//! The method registry: every name `render(method=...)` takes, in one table, with the
//! estimator it runs, the keyword parameters it reads beyond the ones every method takes,
//! the caches it accepts and its defaults. The bindings and the Python package resolve
//! names and check arguments here, so a Rust caller and a Python caller meet the same
//! methods and the same errors.

use super::direct::DirectRenderer;
use super::importance::{ImportanceInputs, ImportanceRenderer};
use super::irradiance::IrradianceRenderer;
use super::many_lights::{ManyLightsRenderer, DEFAULT_VPL_SPP};
use super::output::{RenderOutput, View};
use super::stochastic::{StochasticInputs, StochasticRenderer};
use super::vf::VfRenderer;
use super::{RenderParams, MAX_SPP};
use crate::error::{Error, Result};
use crate::estimators::direct::Method;
use crate::estimators::importance::records::ImportanceCache;
use crate::estimators::indirect::MAX_BOUNCES;
use crate::estimators::irradiance::cache::{IrradianceCache, IrradianceParams};
use crate::estimators::many_lights::{Sampling, MAX_SPP as MANY_LIGHT_MAX_SPP};
use crate::estimators::vf::VfParams;
use crate::geometry::Scene;
use crate::lights::envmap::EnvMap;
use crate::lights::vpl::VplSet;
use crate::visibility::cache::VisibilityCache;

/// A cache a method may take (`cache=`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CacheKind {
    /// [`crate::visibility::cache::VisibilityCache`] (CAM08's records).
    Visibility,
    /// [`IrradianceCache`] (the survey's ch. 3 records).
    Irradiance,
    /// [`ImportanceCache`] (the survey's ch. 6 records).
    Importance,
}

/// A cache handed to a render (`cache=`), of any kind a method may take.
#[derive(Clone, Copy, Debug)]
pub enum CacheRef<'a> {
    Visibility(&'a VisibilityCache),
    Irradiance(&'a IrradianceCache),
    Importance(&'a ImportanceCache),
}

impl<'a> CacheRef<'a> {
    /// Its kind.
    pub fn kind(self) -> CacheKind {
        match self {
            CacheRef::Visibility(_) => CacheKind::Visibility,
            CacheRef::Irradiance(_) => CacheKind::Irradiance,
            CacheRef::Importance(_) => CacheKind::Importance,
        }
    }

    /// The visibility cache, if it is one.
    pub fn visibility(self) -> Option<&'a VisibilityCache> {
        match self {
            CacheRef::Visibility(c) => Some(c),
            _ => None,
        }
    }

    /// The irradiance cache, if it is one.
    pub fn irradiance(self) -> Option<&'a IrradianceCache> {
        match self {
            CacheRef::Irradiance(c) => Some(c),
            _ => None,
        }
    }

    /// The importance cache, if it is one.
    pub fn importance(self) -> Option<&'a ImportanceCache> {
        match self {
            CacheRef::Importance(c) => Some(c),
            _ => None,
        }
    }
}

impl CacheKind {
    /// The name the errors and Python use.
    pub const fn name(self) -> &'static str {
        match self {
            CacheKind::Visibility => "VisibilityCache",
            CacheKind::Irradiance => "IrradianceCache",
            CacheKind::Importance => "ImportanceCache",
        }
    }
}

/// Everything a render by any method may read: the scene, its lighting and the view, and
/// the keyword parameters as the caller set them (`None`: the method's default). A method
/// reads what its row's [`MethodSpec::params`] name besides [`COMMON_PARAMS`].
#[derive(Clone, Copy)]
pub struct MethodInputs<'a> {
    pub scene: &'a Scene,
    pub env: &'a EnvMap,
    pub view: View<'a>,
    /// Worker threads (`None`: every core).
    pub threads: Option<usize>,
    /// Samples per pixel; `None`: the row's [`MethodSpec::default_spp`], or as many as fit
    /// a time budget.
    pub spp: Option<u32>,
    /// Indirect bounces; `None`: the row's [`MethodSpec::default_bounces`].
    pub bounces: Option<u32>,
    /// Adaptive per-pixel counts; `None`: under a time budget only.
    pub adaptive: Option<bool>,
    /// Light draws per sample of the product methods; `None`: one, or chosen from the view
    /// under a time budget.
    pub light_samples: Option<u32>,
    /// The common parameters (`seed`, `time_budget`, `jitter`, `direct`) and the
    /// pass-layer methods' own. Its `spp`, `method`, `bounces`, `adaptive`,
    /// `light_samples` and `auto_light_samples` are set from the fields above and the row.
    pub params: RenderParams,
    /// A cache of a kind the method takes ([`MethodSpec::caches`]).
    pub cache: Option<CacheRef<'a>>,
    /// Method "irradiance_cache" given no cache: the parameters of the one it builds
    /// (`None`: the defaults).
    pub irradiance: Option<IrradianceParams>,
    /// The many-light methods' VPLs; `None`: a default set traced for the view.
    pub vpls: Option<&'a VplSet>,
    /// The many-light methods' bound of the geometry term (1/m²).
    pub clamp: Option<f32>,
    /// VPLs drawn per pixel sample by method "vpl_sampled".
    pub vpl_samples: Option<u32>,
    /// What method "vpl_sampled" draws VPLs by; `None`: [`Sampling::Unoccluded`].
    pub sampling: Option<Sampling>,
    /// Method "vf"'s parameters (`None`: [`VfParams::DEFAULT`]).
    pub vf: Option<VfParams>,
    /// Method "importance_cache"'s own parameters (`None`: all defaults).
    pub importance: Option<ImportanceInputs<'a>>,
    /// Method "stochastic"'s proxies, probabilities and probe rays (`None`: none given).
    pub stochastic: Option<StochasticInputs<'a>>,
}

impl<'a> MethodInputs<'a> {
    /// Every parameter at its default.
    pub fn new(scene: &'a Scene, env: &'a EnvMap, view: View<'a>) -> Self {
        Self {
            scene,
            env,
            view,
            threads: None,
            spp: None,
            bounces: None,
            adaptive: None,
            light_samples: None,
            params: RenderParams::DEFAULT,
            cache: None,
            irradiance: None,
            vpls: None,
            clamp: None,
            vpl_samples: None,
            sampling: None,
            vf: None,
            importance: None,
            stochastic: None,
        }
    }

    /// The samples per pixel of a render by `spec`: the given count, else the row's default
    /// without a time budget and its [`MethodSpec::max_spp`] (as many as fit) with one.
    pub fn spp_for(&self, spec: &MethodSpec) -> u32 {
        match (self.spp, self.params.time_budget) {
            (Some(n), _) => n,
            (None, None) => spec.default_spp,
            (None, Some(_)) => spec.max_spp,
        }
    }

    /// The indirect bounces of a render by `spec`: the given count (at least the row's
    /// least, at most [`MAX_BOUNCES`]), else the row's default.
    pub fn bounces_for(&self, spec: &MethodSpec) -> Result<u32> {
        match self.bounces {
            Some(b) => {
                crate::error::check_range("bounces", b, spec.min_bounces, MAX_BOUNCES)?;
                Ok(b)
            }
            None => Ok(spec.default_bounces),
        }
    }
}

/// How a registered method renders: what its row points at. The renderer reads the inputs
/// its row declares and returns the image with its figures; the pass layer
/// ([`super::passes::run_passes`]) gives it budget, progress, Ctrl-C and determinism.
pub trait MethodRenderer: Sync {
    /// The family it belongs to, as [`METHODS`] lists it ("direct", "many_lights", ...).
    fn family(&self) -> &'static str;

    /// Renders `inputs` as method `spec`. `progress(done, planned)` (pixel samples) is
    /// called on the calling thread about every 0.1 s; a `false` stops the render.
    fn render(
        &self,
        spec: &MethodSpec,
        inputs: &MethodInputs<'_>,
        progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
    ) -> Result<RenderOutput>;
}

/// One row of the registry.
#[derive(Clone, Copy)]
pub struct MethodSpec {
    /// The name `render(method=...)` takes.
    pub name: &'static str,
    /// One line on what it estimates and how.
    pub about: &'static str,
    /// What renders it.
    pub renderer: &'static dyn MethodRenderer,
    /// Keyword parameters the method reads beyond [`COMMON_PARAMS`].
    pub params: &'static [&'static str],
    /// Caches it accepts; empty: none.
    pub caches: &'static [CacheKind],
    /// Least and default indirect bounces.
    pub min_bounces: u32,
    pub default_bounces: u32,
    /// Samples per pixel without `spp` or a time budget.
    pub default_spp: u32,
    /// Most samples per pixel it takes (what a time budget alone aims at).
    pub max_spp: u32,
}

impl std::fmt::Debug for MethodSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MethodSpec")
            .field("name", &self.name)
            .field("family", &self.renderer.family())
            .finish_non_exhaustive()
    }
}

/// Keyword parameters every method takes.
pub const COMMON_PARAMS: &[&str] = &[
    "camera",
    "spp",
    "seed",
    "threads",
    "progress",
    "time_budget",
    "envmap",
    "jitter",
    "bounces",
    "direct",
];

/// What the pass-layer methods read besides the common parameters.
const PASS_PARAMS: &[&str] = &["gbuffer", "adaptive"];
const PRODUCT_PARAMS: &[&str] = &[
    "gbuffer",
    "adaptive",
    "product_level",
    "technique_weights",
    "light_samples",
    "learn_techniques",
];
const CV_PARAMS: &[&str] = &[
    "gbuffer",
    "adaptive",
    "product_level",
    "technique_weights",
    "light_samples",
    "cache",
    "preset",
    "alpha",
    "alpha_radius",
    "insert_missing",
];

/// What method "irradiance_cache" reads besides the common parameters: the pass layer's,
/// a cache, and the parameters of the cache it builds without one.
const IRRADIANCE_PARAMS: &[&str] = &[
    "gbuffer",
    "adaptive",
    "cache",
    "a",
    "strata",
    "r_min",
    "r_max",
    "gradients",
    "clamp_neighbours",
    "secondary_spp",
];

/// What method "vf" reads besides the common parameters ([`VfParams`]' fields).
pub const VF_PARAMS: &[&str] = &[
    "proxies",
    "voxels",
    "marching",
    "indirect",
    "rays_per_pixel",
    "filter",
    "depth_tol",
    "normal_tol",
    "sh_range",
];

/// What method "importance_cache" reads besides the common parameters: the VPLs, a cache,
/// the draws per row, the combination and its confidences, eq. 6.3's `λ` and the
/// parameters of the cache it builds without one.
const IMPORTANCE_PARAMS: &[&str] = &[
    "vpls",
    "cache",
    "vpl_samples",
    "combine",
    "alpha",
    "lam",
    "spacing",
    "nearest",
];

/// What method "stochastic" reads besides the common parameters: the proxy set, how the
/// probabilities are chosen and the probes per pixel.
const STOCHASTIC_PARAMS: &[&str] = &["proxies", "probabilities", "probe_rays"];

/// Samples per pixel of method "irradiance_cache" without `spp` or a time budget: its
/// samples antialias the interpolated bounce, trace Phong's specular part of it and the
/// few points no record serves (and estimate direct light, if asked). At 256x192 with the
/// default cache, 16 rather than 4 took the garage's (sun) relMSE from 0.0106 to 0.0042
/// and room's (sunlit) from 8.1e-4 to 3.9e-4, for about a quarter more time.
pub const DEFAULT_IRRADIANCE_SPP: u32 = 16;

/// Samples per pixel of the pass-layer methods without `spp` or a time budget.
pub const DEFAULT_DIRECT_SPP: u32 = 16;

const fn direct(
    name: &'static str,
    about: &'static str,
    renderer: &'static DirectRenderer,
    params: &'static [&'static str],
) -> MethodSpec {
    MethodSpec {
        name,
        about,
        renderer,
        params,
        caches: &[],
        min_bounces: 0,
        default_bounces: 0,
        default_spp: DEFAULT_DIRECT_SPP,
        max_spp: MAX_SPP,
    }
}

/// Every method, in the order the errors list them.
pub const METHODS: &[MethodSpec] = &[
    direct(
        "env",
        "light sampling: the map's distribution, a point on each area light",
        &DirectRenderer(Method::Env),
        PASS_PARAMS,
    ),
    direct(
        "bsdf",
        "BSDF sampling",
        &DirectRenderer(Method::Bsdf),
        PASS_PARAMS,
    ),
    direct(
        "mis",
        "light and BSDF sampling with the power heuristic",
        &DirectRenderer(Method::Mis),
        PASS_PARAMS,
    ),
    direct(
        "product",
        "product sampling of map x BSDF (CAM08 sec. 5.5) in a one-sample mixture",
        &DirectRenderer(Method::Product),
        PRODUCT_PARAMS,
    ),
    MethodSpec {
        caches: &[CacheKind::Visibility],
        ..direct(
            "cv",
            "product sampling with the cache's L B~ V~ as a control variate (CAM08 eq. 2-3)",
            &DirectRenderer(Method::ControlVariate),
            CV_PARAMS,
        )
    },
    MethodSpec {
        min_bounces: 1,
        default_bounces: 1,
        ..direct(
            "path",
            "the unbiased reference with indirect light: MIS at every path vertex",
            &DirectRenderer(Method::Mis),
            PASS_PARAMS,
        )
    },
    MethodSpec {
        name: "irradiance_cache",
        about: "one bounce of diffuse light interpolated from irradiance records with \
                gradients (survey ch. 3); Phong's specular bounce by paths",
        renderer: &IrradianceRenderer,
        params: IRRADIANCE_PARAMS,
        caches: &[CacheKind::Irradiance],
        min_bounces: 1,
        default_bounces: 1,
        default_spp: DEFAULT_IRRADIANCE_SPP,
        max_spp: MAX_SPP,
    },
    MethodSpec {
        name: "vpl",
        about: "every virtual point light summed, one shadow ray each (survey eq. 6.1)",
        renderer: &ManyLightsRenderer { sampled: false },
        params: &["vpls", "clamp"],
        caches: &[],
        min_bounces: 1,
        default_bounces: 1,
        default_spp: DEFAULT_VPL_SPP,
        max_spp: MANY_LIGHT_MAX_SPP,
    },
    MethodSpec {
        name: "vpl_sampled",
        about: "virtual point lights drawn by their unoccluded contribution, their power or \
                uniformly (sampling=)",
        renderer: &ManyLightsRenderer { sampled: true },
        params: &["vpls", "clamp", "vpl_samples", "sampling"],
        caches: &[],
        min_bounces: 1,
        default_bounces: 1,
        default_spp: DEFAULT_VPL_SPP,
        max_spp: MANY_LIGHT_MAX_SPP,
    },
    MethodSpec {
        name: "importance_cache",
        about: "virtual point lights drawn from the importance cache's records near each \
                sample, rows F, U, B, C combined by alpha-max or balance (survey eq. 6.2-6.6)",
        renderer: &ImportanceRenderer,
        params: IMPORTANCE_PARAMS,
        caches: &[CacheKind::Importance],
        min_bounces: 1,
        default_bounces: 1,
        default_spp: DEFAULT_VPL_SPP,
        max_spp: MANY_LIGHT_MAX_SPP,
    },
    MethodSpec {
        name: "vf",
        about: "visibility filtering: VPLs of point proxies in a voxel grid, visibility by \
                sparse marching and a geometry-aware filter, far voxels in SH (VF eq. 1-7)",
        renderer: &VfRenderer,
        params: VF_PARAMS,
        caches: &[],
        min_bounces: 1,
        default_bounces: 1,
        default_spp: DEFAULT_DIRECT_SPP,
        max_spp: MAX_SPP,
    },
    MethodSpec {
        name: "stochastic",
        about: "light sampling with probabilistic visibility on geometry proxies: each shadow \
                ray tests the proxies, the scene or a correction term, unbiased (BLD eq. 8, \
                splitting eq. 27)",
        renderer: &StochasticRenderer,
        params: STOCHASTIC_PARAMS,
        caches: &[],
        min_bounces: 0,
        default_bounces: 0,
        default_spp: DEFAULT_DIRECT_SPP,
        max_spp: MAX_SPP,
    },
];

/// The names of every method, in registry order.
pub fn names() -> Vec<&'static str> {
    METHODS.iter().map(|m| m.name).collect()
}

/// The method called `name`; an error naming `method` and listing every name otherwise.
pub fn method(name: &str) -> Result<&'static MethodSpec> {
    METHODS.iter().find(|m| m.name == name).ok_or_else(|| {
        Error::invalid(
            "method",
            format!("expected one of {:?}, got {name:?}", names()),
        )
    })
}

impl MethodSpec {
    /// Whether the method reads keyword parameter `name`.
    pub fn takes(&self, name: &str) -> bool {
        COMMON_PARAMS.contains(&name) || self.params.contains(&name)
    }

    /// Fails, naming the first parameter of `given` (those the caller set) that the method
    /// does not read, with what it does read; a `cache` must also be of a kind it accepts
    /// (`cache_kind`).
    pub fn check_args(&self, given: &[&str], cache_kind: Option<CacheKind>) -> Result<()> {
        if let Some(bad) = given.iter().find(|p| !self.takes(p)) {
            let takers: Vec<&str> = METHODS
                .iter()
                .filter(|m| m.params.contains(bad))
                .map(|m| m.name)
                .collect();
            return Err(Error::invalid(
                *bad,
                format!(
                    "method {:?} does not take it (methods that do: {takers:?}); it takes \
                     {:?} besides {:?}",
                    self.name, self.params, COMMON_PARAMS
                ),
            ));
        }
        match cache_kind {
            Some(kind) if !self.caches.contains(&kind) => Err(Error::invalid(
                "cache",
                format!(
                    "method {:?} takes {}, got a {}",
                    self.name,
                    match self.caches {
                        [] => "no cache".to_string(),
                        kinds => format!(
                            "a {}",
                            kinds
                                .iter()
                                .map(|k| k.name())
                                .collect::<Vec<_>>()
                                .join(" or ")
                        ),
                    },
                    kind.name()
                ),
            )),
            _ => Ok(()),
        }
    }

    /// Renders `inputs` with this method: checks the inputs it does not read are unset and
    /// a cache is of a kind it takes, then runs its renderer ([`MethodRenderer::render`]).
    pub fn render(
        &self,
        inputs: &MethodInputs<'_>,
        progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
    ) -> Result<RenderOutput> {
        let given: Vec<&str> = [
            ("vpls", inputs.vpls.is_some()),
            ("clamp", inputs.clamp.is_some()),
            ("vpl_samples", inputs.vpl_samples.is_some()),
            ("sampling", inputs.sampling.is_some()),
            ("gbuffer", matches!(inputs.view, View::GBuffer(_))),
            ("adaptive", inputs.adaptive == Some(true)),
            ("light_samples", inputs.light_samples.is_some()),
            ("a", inputs.irradiance.is_some()),
            ("proxies", inputs.vf.is_some()),
            ("combine", inputs.importance.is_some()),
            (
                "probabilities",
                inputs.stochastic.is_some_and(|s| s.probabilities.is_some()),
            ),
            (
                "probe_rays",
                inputs.stochastic.is_some_and(|s| s.probe_rays.is_some()),
            ),
            (
                "proxies",
                inputs.stochastic.is_some_and(|s| s.proxies.is_some()),
            ),
        ]
        .into_iter()
        .filter_map(|(name, set)| set.then_some(name))
        .collect();
        let kind = inputs.cache.map(CacheRef::kind);
        self.check_args(&given, kind)?;
        self.renderer.render(self, inputs, progress)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::output::Stat;

    /// Every direct [`Method`] has a row under its own name; names are unique; every row's
    /// parameters are disjoint from the common ones.
    #[test]
    fn the_table_covers_every_method_once() {
        for m in Method::ALL {
            let spec = method(m.name()).unwrap();
            assert_eq!(spec.renderer.family(), "direct");
        }
        let mut names = names();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), METHODS.len());
        for spec in METHODS {
            assert!(spec.params.iter().all(|p| !COMMON_PARAMS.contains(p)));
            assert!(spec.min_bounces <= spec.default_bounces);
        }
    }

    /// An unknown name lists the names; a parameter a method does not read is named with
    /// what the method takes; caches only where declared.
    #[test]
    fn errors_name_what_the_method_takes() {
        let e = method("foo").unwrap_err().to_string();
        assert!(e.contains("method") && e.contains("\"cv\"") && e.contains("\"vpl_sampled\""));
        let mis = method("mis").unwrap();
        assert!(mis.check_args(&["spp", "gbuffer"], None).is_ok());
        let e = mis
            .check_args(&["spp", "alpha"], None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("alpha") && e.contains("\"mis\"") && e.contains("gbuffer"));
        assert!(
            e.contains("methods that do: [\"cv\", \"importance_cache\"]"),
            "{e}"
        );
        let e = mis
            .check_args(&[], Some(CacheKind::Visibility))
            .unwrap_err()
            .to_string();
        assert!(e.contains("no cache"), "{e}");
        let cv = method("cv").unwrap();
        assert!(cv
            .check_args(&["alpha", "cache"], Some(CacheKind::Visibility))
            .is_ok());
        assert!(method("vpl")
            .unwrap()
            .check_args(&["vpl_samples"], None)
            .is_err());
    }

    /// "path" takes one bounce by default and at least one; the many-light methods one
    /// sample per pixel; the others none and 16.
    #[test]
    fn defaults_come_from_the_row() {
        let path = method("path").unwrap();
        assert_eq!((path.min_bounces, path.default_bounces), (1, 1));
        assert_eq!(method("cv").unwrap().default_bounces, 0);
        assert_eq!(method("cv").unwrap().default_spp, DEFAULT_DIRECT_SPP);
        assert_eq!(method("vpl").unwrap().default_spp, DEFAULT_VPL_SPP);
        assert_eq!(method("vpl").unwrap().renderer.family(), "many_lights");
    }

    /// A method added as a row and a renderer alone — every sample a constant — gets its
    /// default samples, a time budget, stopping and its figures from the pass layer
    /// through [`MethodSpec::render`], and the registry's checks of what it does not read.
    #[test]
    fn a_new_method_is_a_row_and_a_renderer() {
        use crate::render::estimator::{PassPlan, PixelEstimator, PixelPass, PixelTiming};
        use crate::render::output::Stats;
        use crate::render::passes::{run_passes, PassParams};
        use crate::render::sums::CvSums;

        const LEVEL: f32 = 0.25;

        struct Constant;

        impl PixelPass for Constant {
            type Work = ();
            type Note = ();
            type Sums = CvSums;

            fn shade_pixel(
                &self,
                _pixel: usize,
                samples: std::ops::Range<u32>,
                acc: &mut CvSums,
                _work: &mut (),
                _note: &mut (),
            ) -> PixelTiming {
                for _ in samples {
                    acc.add(glam::Vec3::splat(LEVEL), [0.0; 3]);
                    // A cost to budget against.
                    std::hint::black_box((0..2000).sum::<u64>());
                }
                PixelTiming::default()
            }
        }

        impl PixelEstimator for Constant {
            type Work = ();
            type Note = ();
            type Sums = CvSums;
            type Pass<'a> = Constant;

            fn pass<R>(&self, _plan: &PassPlan, run: impl FnOnce(&Constant) -> R) -> R {
                run(self)
            }
        }

        struct ConstantRenderer;

        impl MethodRenderer for ConstantRenderer {
            fn family(&self) -> &'static str {
                "toy"
            }

            fn render(
                &self,
                spec: &MethodSpec,
                inputs: &MethodInputs<'_>,
                progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
            ) -> Result<RenderOutput> {
                let cam = inputs.view.camera();
                let (w, h) = (cam.width, cam.height);
                let params = PassParams {
                    spp: inputs.spp_for(spec),
                    time_budget: inputs.params.time_budget,
                    adaptive: false,
                    first_spp: None,
                };
                let start = std::time::Instant::now();
                let run = run_passes(
                    &mut Constant,
                    w as usize,
                    h as usize,
                    &params,
                    start,
                    inputs.threads,
                    progress,
                )?;
                let mut stats = Stats::default();
                stats.set("method", spec.name);
                stats.set("spp", run.min_spp());
                stats.set("passes", run.passes);
                stats.set("complete", run.complete);
                let (image, variance) = run
                    .sums
                    .iter()
                    .map(|s| {
                        let (mean, var) = s.estimate([0.0; 3]);
                        (mean.map(|m| m as f32), var.map(|v| v as f32))
                    })
                    .unzip();
                Ok(RenderOutput {
                    width: w,
                    height: h,
                    image,
                    variance,
                    alpha: None,
                    sample_counts: run.counts(),
                    stats,
                })
            }
        }

        let toy = MethodSpec {
            name: "toy",
            about: "a constant",
            renderer: &ConstantRenderer,
            params: &[],
            caches: &[],
            min_bounces: 0,
            default_bounces: 0,
            default_spp: 3,
            max_spp: MAX_SPP,
        };
        let setup = crate::scenes::load("cornell", 0.25, 0).unwrap();
        let cam = setup.camera.with_resolution(24, 16).unwrap();
        let inputs = MethodInputs::new(&setup.scene, &setup.envmap, View::Camera(&cam));
        let mut reports = 0;
        let out = toy
            .render(&inputs, &mut |_, _| {
                reports += 1;
                true
            })
            .unwrap();
        assert!(out.sample_counts.iter().all(|&n| n == 3));
        assert!(out.image.iter().all(|p| *p == [LEVEL; 3]));
        assert_eq!(out.stats.get("complete"), Some(&Stat::Bool(true)));
        assert!(reports >= 1);
        // A budget alone: as many samples as fit, at least one per pixel.
        let budgeted = MethodInputs {
            params: RenderParams {
                time_budget: Some(0.05),
                ..RenderParams::DEFAULT
            },
            ..inputs
        };
        let out = toy.render(&budgeted, &mut |_, _| true).unwrap();
        assert!(out.sample_counts.iter().all(|&n| n >= 1));
        assert!(matches!(out.stats.get("passes"), Some(Stat::Int(p)) if *p >= 1));
        // A stop leaves pixels at the samples they took.
        let out = toy.render(&budgeted, &mut |_, _| false).unwrap();
        assert!(out.sample_counts.iter().all(|&n| n <= MAX_SPP));
        // What the row does not declare is refused, naming it.
        let cache = VisibilityCache::new(crate::visibility::params::CacheParams::MEDIUM).unwrap();
        let with_cache = MethodInputs {
            cache: Some(CacheRef::Visibility(&cache)),
            ..inputs
        };
        let e = toy.render(&with_cache, &mut |_, _| true).unwrap_err();
        assert!(e.to_string().starts_with("cache"), "{e}");
        let with_clamp = MethodInputs {
            clamp: Some(1.0),
            ..inputs
        };
        let e = toy.render(&with_clamp, &mut |_, _| true).unwrap_err();
        assert!(e.to_string().starts_with("clamp"), "{e}");
    }

    /// The direct rows render what [`crate::render::render`] renders, bit for bit; the
    /// many-light rows refuse a depth beside a given set.
    #[test]
    fn rows_render_through_their_renderers() {
        let setup = crate::scenes::load("cornell", 0.25, 0).unwrap();
        let cam = setup.camera.with_resolution(16, 12).unwrap();
        let inputs = MethodInputs {
            spp: Some(2),
            threads: Some(2),
            ..MethodInputs::new(&setup.scene, &setup.envmap, View::Camera(&cam))
        };
        let via_row = method("path")
            .unwrap()
            .render(&inputs, &mut |_, _| true)
            .unwrap();
        let direct = crate::render::render(
            &setup.scene,
            &setup.envmap,
            &cam,
            &RenderParams::path(1, 2),
            None,
            Some(1),
            &mut |_, _| true,
        )
        .unwrap();
        let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&via_row.image), bits(&direct.image));
        assert_eq!(via_row.stats.get("method"), Some(&Stat::Text("path")));
        assert_eq!(via_row.stats.get("bounces"), Some(&Stat::Int(1)));
        let e = method("path")
            .unwrap()
            .render(
                &MethodInputs {
                    bounces: Some(0),
                    ..inputs
                },
                &mut |_, _| true,
            )
            .unwrap_err();
        assert!(e.to_string().starts_with("bounces"), "{e}");
        let vpl = method("vpl").unwrap();
        let out = vpl.render(&inputs, &mut |_, _| true).unwrap();
        assert!(out.sample_counts.iter().all(|&n| n == 2));
        assert!(matches!(
            out.stats.get("vpl_trace_seconds"),
            Some(Stat::Float(_))
        ));
        let set = crate::render::many_lights::default_vpls(
            &setup.scene,
            &setup.envmap,
            &cam,
            0,
            1,
            true,
            None,
        )
        .unwrap();
        let e = vpl
            .render(
                &MethodInputs {
                    vpls: Some(&set),
                    bounces: Some(2),
                    ..inputs
                },
                &mut |_, _| true,
            )
            .unwrap_err();
        assert!(e.to_string().starts_with("bounces"), "{e}");
        let e = vpl
            .render(
                &MethodInputs {
                    vpl_samples: Some(4),
                    ..inputs
                },
                &mut |_, _| true,
            )
            .unwrap_err();
        assert!(e.to_string().starts_with("vpl_samples"), "{e}");
    }
}
