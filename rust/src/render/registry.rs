//! The method registry: every name `render(method=...)` takes, in one table, with the
//! estimator it runs, the keyword parameters it reads beyond the ones every method takes,
//! the caches it accepts and its defaults. The bindings and the Python package resolve
//! names and check arguments here, so a Rust caller and a Python caller meet the same
//! methods and the same errors.

use crate::error::{Error, Result};
use crate::estimators::direct::Method;

/// A cache a method may take (`cache=`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CacheKind {
    /// [`crate::visibility::cache::VisibilityCache`] (CAM08's records).
    Visibility,
}

impl CacheKind {
    /// The name the errors and Python use.
    pub const fn name(self) -> &'static str {
        match self {
            CacheKind::Visibility => "VisibilityCache",
        }
    }
}

/// What a method runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Estimator {
    /// A direct-lighting [`Method`] on the pass layer, with `bounces` of path-traced
    /// indirect light added when asked ([`super::RenderParams`]).
    Direct(Method),
    /// The many-light renderer over virtual point lights
    /// ([`crate::estimators::many_lights`]); `sampled`: VPLs drawn per sample instead of
    /// every VPL summed.
    ManyLights { sampled: bool },
}

/// One row of the registry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MethodSpec {
    /// The name `render(method=...)` takes.
    pub name: &'static str,
    /// One line on what it estimates and how.
    pub about: &'static str,
    pub estimator: Estimator,
    /// Keyword parameters the method reads beyond [`COMMON_PARAMS`].
    pub params: &'static [&'static str],
    /// Caches it accepts; empty: none.
    pub caches: &'static [CacheKind],
    /// Least and default indirect bounces.
    pub min_bounces: u32,
    pub default_bounces: u32,
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

const fn direct(
    name: &'static str,
    about: &'static str,
    method: Method,
    params: &'static [&'static str],
) -> MethodSpec {
    MethodSpec {
        name,
        about,
        estimator: Estimator::Direct(method),
        params,
        caches: &[],
        min_bounces: 0,
        default_bounces: 0,
    }
}

/// Every method, in the order the errors list them.
pub const METHODS: &[MethodSpec] = &[
    direct(
        "env",
        "light sampling: the map's distribution, a point on each area light",
        Method::Env,
        PASS_PARAMS,
    ),
    direct("bsdf", "BSDF sampling", Method::Bsdf, PASS_PARAMS),
    direct(
        "mis",
        "light and BSDF sampling with the power heuristic",
        Method::Mis,
        PASS_PARAMS,
    ),
    direct(
        "product",
        "product sampling of map x BSDF (CAM08 sec. 5.5) in a one-sample mixture",
        Method::Product,
        PRODUCT_PARAMS,
    ),
    MethodSpec {
        caches: &[CacheKind::Visibility],
        ..direct(
            "cv",
            "product sampling with the cache's L B~ V~ as a control variate (CAM08 eq. 2-3)",
            Method::ControlVariate,
            CV_PARAMS,
        )
    },
    MethodSpec {
        min_bounces: 1,
        default_bounces: 1,
        ..direct(
            "path",
            "the unbiased reference with indirect light: MIS at every path vertex",
            Method::Mis,
            PASS_PARAMS,
        )
    },
    MethodSpec {
        name: "vpl",
        about: "every virtual point light summed, one shadow ray each (survey eq. 6.1)",
        estimator: Estimator::ManyLights { sampled: false },
        params: &["vpls", "clamp"],
        caches: &[],
        min_bounces: 1,
        default_bounces: 1,
    },
    MethodSpec {
        name: "vpl_sampled",
        about: "virtual point lights drawn by their unoccluded contribution",
        estimator: Estimator::ManyLights { sampled: true },
        params: &["vpls", "clamp", "vpl_samples"],
        caches: &[],
        min_bounces: 1,
        default_bounces: 1,
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

    /// The renderer's parameters of a direct method with `spp` samples and its default
    /// bounces; `None` for the many-light methods.
    pub fn render_params(&self, spp: u32) -> Option<super::RenderParams> {
        match self.estimator {
            Estimator::Direct(method) => Some(super::RenderParams {
                bounces: self.default_bounces,
                ..super::RenderParams::with(method, spp)
            }),
            Estimator::ManyLights { .. } => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every direct [`Method`] has a row under its own name; names are unique; every row's
    /// parameters are disjoint from the common ones.
    #[test]
    fn the_table_covers_every_method_once() {
        for m in Method::ALL {
            let spec = method(m.name()).unwrap();
            assert_eq!(spec.estimator, Estimator::Direct(m));
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
        assert!(e.contains("methods that do: [\"cv\"]"), "{e}");
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

    /// "path" is MIS with one bounce by default; a many-light method has no pass-layer
    /// parameters.
    #[test]
    fn defaults_come_from_the_row() {
        let p = method("path").unwrap().render_params(8).unwrap();
        assert_eq!((p.method, p.bounces, p.spp), (Method::Mis, 1, 8));
        assert_eq!(method("cv").unwrap().render_params(4).unwrap().bounces, 0);
        assert!(method("vpl").unwrap().render_params(4).is_none());
    }
}
