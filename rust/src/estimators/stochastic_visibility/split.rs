//! One shadow ray's stochastic visibility with visibility splitting (BLD §4.3, eq. 25–27)
//! and the probe rays of §4.1, on a scene `P` and a proxy set `P'`.
//!
//! ## Splitting (eq. 27)
//! A shading point on object `O` lies inside `O`'s own outside proxy, so `V_P'` would be 0
//! for all its rays (eq. 25–26). The ray's visibility is split as `V = V_E · Ṽ_R`: `E`
//! holds `O` and every object the set has no proxy for, tested exactly; `R`, every other
//! object, is estimated by eq. 8 against the proxies of `R` (never `O`'s). Eq. 8's terms
//! then read, with `V_R'` the proxies' answer:
//!
//! | term | value | traces |
//! |---|---|---|
//! | (a) | `V_R' V_E / p1` | `P'`; `E` only where `V_R' = 1` |
//! | (b) | `(1 − V_R') V_E V_R / p2` | `P'`; the whole scene (`V_E V_R = V_P`) only where `V_R' = 0` |
//! | (c) | `−V_R' V_E (1 − V_R) / p3` | `P'`; `E`, then `R`, only where `V_R' = 1` |
//!
//! so no scene ray is traced where the proxy already decides the term (eq. 8's remark).
//! The test against `E` alone is the scene's object filter
//! ([`Scene::occluded1_objects`]); when `E` is `O` alone it stops at the ray's exit from
//! `O`'s bounding box (nothing of `O` lies beyond), so it visits few nodes.
//!
//! ## Solid outside proxies
//! A segment lying wholly inside an outside proxy crosses none of its triangles, yet may
//! hit the object inside: outside proxies are solid. A shading point inside the proxy of an
//! object of `R` (a point on the ground under a tree's box) has `V_R' = 0` for every ray;
//! a segment ending inside one but starting outside crosses its surface. Whether a point is
//! inside a proxy is decided by its planes for a convex proxy (boxes, hulls: checked once
//! when the set is prepared) and by the parity of a ray's crossings otherwise; each proxy's
//! triangles must form a closed surface (the builders' guarantee; taken on trust for
//! [`ProxySet::from_meshes`]).
//!
//! An area light's own object stays in `R`: a thick emitter's proxy blocks the segments
//! that end on it, whose rays then take term (b) (unbiased, more variance); flat lights
//! (quads) have flat boxes that a segment ending short of the light never crosses.

use glam::Vec3;

use super::{Fractions, Probabilities, ProxyKind, Term};
use crate::error::{Error, Result};
use crate::geometry::proxies::ProxySet;
use crate::geometry::{Bounds, Scene, TraversalCounters};

/// How the probabilities of eq. 8 are chosen at a point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ProbabilityMode {
    /// [`Probabilities::equal`]: no probe rays.
    Equal,
    /// Least variance (§4.1, eq. 14) from fractions measured by probe rays
    /// ([`Probabilities::least_variance`]).
    Optimal,
    /// Least variance, then the cost heuristic of eq. 22–24
    /// ([`Probabilities::cost_heuristic`]); per point, so a closed form rather than
    /// [`Probabilities::least_work`]'s search.
    Cost,
}

impl ProbabilityMode {
    /// Every mode, in the order the errors list them.
    pub const ALL: [ProbabilityMode; 3] = [Self::Equal, Self::Optimal, Self::Cost];

    /// The name `probabilities=` takes.
    pub const fn name(self) -> &'static str {
        match self {
            Self::Equal => "equal",
            Self::Optimal => "optimal",
            Self::Cost => "cost",
        }
    }

    /// The mode called `name`; an error naming `probabilities` otherwise.
    pub fn parse(name: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| {
                Error::invalid(
                    "probabilities",
                    format!(
                        "expected one of {:?}, got {name:?}",
                        Self::ALL.map(|m| m.name())
                    ),
                )
            })
    }

    /// Whether it traces probe rays.
    pub const fn probes(self) -> bool {
        !matches!(self, Self::Equal)
    }
}

/// Least probability a needed term keeps under probed probabilities: fractions from 16
/// probes are rough, and a term at 0.05 weighs its rays by at most 20.
pub const PROBE_FLOOR: f64 = 0.05;

/// Beta prior added to each ray type's probe count ([`Fractions::from_counts`]).
pub const PROBE_PRIOR: f64 = 0.5;

/// What the shadow rays of a band did, for the render's figures (Table 5's rows).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ShadowWork {
    /// Shadow rays estimated (eq. 8 draws), probes excluded.
    pub shadow_rays: u64,
    /// Eq. 8's terms drawn: (a), (b), (c).
    pub terms: [u64; 3],
    /// Queries of the proxy set (not made for points inside a solid proxy).
    pub proxy_rays: u64,
    /// Queries of the scene (any filter), probes included.
    pub scene_rays: u64,
    /// Of those, the exact tests of `E` alone (splitting).
    pub split_rays: u64,
    /// Probe rays (each one proxy and one scene query).
    pub probe_rays: u64,
    /// Shadow origins found inside a solid proxy of `R`.
    pub inside_points: u64,
    /// The proxy set's traversal work.
    pub proxy: TraversalCounters,
    /// The scene's traversal work (shadow and probe rays; not the primary rays).
    pub scene: TraversalCounters,
}

impl ShadowWork {
    /// Adds `o`'s counts.
    pub fn merge(&mut self, o: &ShadowWork) {
        self.shadow_rays += o.shadow_rays;
        for i in 0..3 {
            self.terms[i] += o.terms[i];
        }
        self.proxy_rays += o.proxy_rays;
        self.scene_rays += o.scene_rays;
        self.split_rays += o.split_rays;
        self.probe_rays += o.probe_rays;
        self.inside_points += o.inside_points;
        self.proxy += o.proxy;
        self.scene += o.scene;
    }
}

/// A proxy object's solid: how to tell whether a point lies inside it.
#[derive(Clone, Debug)]
struct Solid {
    bounds: Bounds,
    /// Its face planes `(n, d)`, `n·x < d` inside, when it is convex.
    planes: Option<Vec<(Vec3, f32)>>,
    /// Its triangles in the proxy scene's mesh (for the parity test).
    triangles: std::ops::Range<usize>,
}

/// A shading point's split (eq. 27): its object and what its rays need.
#[derive(Clone, Copy, Debug)]
pub struct SplitPoint {
    /// The object hit at the point (`O`).
    pub object: u32,
    /// The proxy object standing for `O`, skipped by proxy queries.
    skip_proxy: u32,
    /// The point lies inside a solid proxy of `R`: `V_R' = 0` for every ray.
    inside: bool,
}

/// Eq. 8 with splitting on a scene and a proxy set (module docs).
pub struct SplitVisibility<'a> {
    scene: &'a Scene,
    proxies: &'a ProxySet,
    /// Per scene object, the proxy object standing for it (`u32::MAX`: none, so in `E`).
    proxy_of: Vec<u32>,
    /// Whether some object has no proxy (then `E` is more than `O`).
    uncovered: bool,
    /// Per scene object, its bounds (the exit of a ray from `O`'s box ends the `E` test).
    object_bounds: Vec<Bounds>,
    /// Per proxy object, its solid (outside proxies only; empty otherwise).
    solids: Vec<Solid>,
}

impl<'a> SplitVisibility<'a> {
    /// Prepares `proxies` for `scene`; fails, naming `proxies`, when the set was built for
    /// another scene.
    pub fn new(scene: &'a Scene, proxies: &'a ProxySet) -> Result<Self> {
        proxies.check_scene(scene)?;
        let mesh = scene.mesh();
        let n = mesh.objects.len();
        let mut proxy_of = vec![u32::MAX; n];
        for (i, &o) in proxies.objects().iter().enumerate() {
            if (o as usize) < n {
                proxy_of[o as usize] = i as u32;
            }
        }
        let object_bounds = mesh
            .objects
            .iter()
            .map(|o| Bounds::of_triangles(&mesh.triangles[o.triangle_range()]))
            .collect();
        let solids = if proxies.kind() == ProxyKind::Outside {
            let pm = proxies.scene().mesh();
            pm.objects
                .iter()
                .map(|o| {
                    let tris = &pm.triangles[o.triangle_range()];
                    Solid {
                        bounds: Bounds::of_triangles(tris),
                        planes: convex_planes(tris),
                        triangles: o.triangle_range(),
                    }
                })
                .collect()
        } else {
            Vec::new()
        };
        Ok(Self {
            scene,
            proxies,
            uncovered: proxy_of.contains(&u32::MAX),
            proxy_of,
            object_bounds,
            solids,
        })
    }

    /// The proxy set's guarantee.
    pub fn kind(&self) -> ProxyKind {
        self.proxies.kind()
    }

    /// The split of a shading point on `object` whose shadow rays leave from `origin`.
    pub fn point(&self, object: u32, origin: Vec3, work: &mut ShadowWork) -> SplitPoint {
        let skip_proxy = self
            .proxy_of
            .get(object as usize)
            .copied()
            .unwrap_or(u32::MAX);
        let inside = self
            .solids
            .iter()
            .enumerate()
            .any(|(i, s)| i as u32 != skip_proxy && self.inside(s, origin));
        work.inside_points += inside as u64;
        SplitPoint {
            object,
            skip_proxy,
            inside,
        }
    }

    /// Whether `p` lies strictly inside solid `s`.
    fn inside(&self, s: &Solid, p: Vec3) -> bool {
        if !(p.cmpgt(s.bounds.min).all() && p.cmplt(s.bounds.max).all()) {
            return false;
        }
        match &s.planes {
            Some(planes) => planes.iter().all(|&(n, d)| n.dot(p) < d),
            None => {
                // Parity of the crossings of a ray in a fixed, axis-free direction.
                let dir = Vec3::new(0.5773, 0.5774, 0.5775).normalize();
                let tris = &self.proxies.scene().mesh().triangles[s.triangles.clone()];
                tris.iter().filter(|t| crosses(p, dir, t)).count() % 2 == 1
            }
        }
    }

    /// `V_R'`: whether the proxies of `R` let the ray through (solid where outside).
    pub fn proxy_visible(
        &self,
        at: &SplitPoint,
        origin: Vec3,
        dir: Vec3,
        tmax: f32,
        work: &mut ShadowWork,
    ) -> bool {
        if at.inside {
            return false;
        }
        work.proxy_rays += 1;
        let skip = at.skip_proxy;
        !self
            .proxies
            .scene()
            .occluded1_objects(origin, dir, tmax, |i| i != skip, &mut work.proxy)
    }

    /// `V_E`: whether `O` and the objects without proxies let the ray through.
    pub fn exact_split(
        &self,
        at: &SplitPoint,
        origin: Vec3,
        dir: Vec3,
        tmax: f32,
        work: &mut ShadowWork,
    ) -> bool {
        let o = at.object;
        let tmax = if self.uncovered {
            tmax
        } else {
            // Nothing of O lies beyond the ray's exit from O's box.
            match self
                .object_bounds
                .get(o as usize)
                .and_then(|b| exit(b, origin, dir))
            {
                Some(t) => t.min(tmax),
                None => return true,
            }
        };
        if tmax <= 0.0 {
            return true;
        }
        work.scene_rays += 1;
        work.split_rays += 1;
        let proxy_of = &self.proxy_of;
        !self.scene.occluded1_objects(
            origin,
            dir,
            tmax,
            |obj| obj == o || proxy_of[obj as usize] == u32::MAX,
            &mut work.scene,
        )
    }

    /// `V_R`: whether the objects with proxies other than `O` let the ray through.
    pub fn exact_rest(
        &self,
        at: &SplitPoint,
        origin: Vec3,
        dir: Vec3,
        tmax: f32,
        work: &mut ShadowWork,
    ) -> bool {
        work.scene_rays += 1;
        let o = at.object;
        let proxy_of = &self.proxy_of;
        !self.scene.occluded1_objects(
            origin,
            dir,
            tmax,
            |obj| obj != o && proxy_of[obj as usize] != u32::MAX,
            &mut work.scene,
        )
    }

    /// `V_P`: the whole scene, unfiltered.
    pub fn exact(&self, origin: Vec3, dir: Vec3, tmax: f32, work: &mut ShadowWork) -> bool {
        work.scene_rays += 1;
        !self.scene.occluded1(origin, dir, tmax, &mut work.scene)
    }

    /// One draw of eq. 8 with splitting (module docs' table) for the ray `origin + t dir`,
    /// `t < tmax`: `u` in `[0, 1)` picks the term. Returns `0`, `1/p` or `−1/p`, unclamped.
    #[allow(clippy::too_many_arguments)]
    pub fn estimate(
        &self,
        p: &Probabilities,
        u: f64,
        at: &SplitPoint,
        origin: Vec3,
        dir: Vec3,
        tmax: f32,
        work: &mut ShadowWork,
    ) -> f64 {
        work.shadow_rays += 1;
        let t = p.choose(u);
        work.terms[t as usize] += 1;
        let pt = p.of(t);
        let proxy = self.proxy_visible(at, origin, dir, tmax, work);
        match t {
            Term::Proxy => {
                if proxy && self.exact_split(at, origin, dir, tmax, work) {
                    1.0 / pt
                } else {
                    0.0
                }
            }
            Term::Over => {
                if !proxy && self.exact(origin, dir, tmax, work) {
                    1.0 / pt
                } else {
                    0.0
                }
            }
            Term::Under => {
                if proxy
                    && self.exact_split(at, origin, dir, tmax, work)
                    && !self.exact_rest(at, origin, dir, tmax, work)
                {
                    -1.0 / pt
                } else {
                    0.0
                }
            }
        }
    }

    /// A probe ray (§4.1): its type (0..4, Table 1's type minus one) for `R`, tracing the
    /// proxies and the scene.
    pub fn probe(
        &self,
        at: &SplitPoint,
        origin: Vec3,
        dir: Vec3,
        tmax: f32,
        work: &mut ShadowWork,
    ) -> usize {
        work.probe_rays += 1;
        let proxy = self.proxy_visible(at, origin, dir, tmax, work);
        let scene = self.exact_rest(at, origin, dir, tmax, work);
        match (scene, proxy) {
            (false, false) => 0,
            (false, true) => 1,
            (true, false) => 2,
            (true, true) => 3,
        }
    }

    /// The probabilities of `mode` from probe counts (`counts[i]` rays of type `i + 1`).
    pub fn probabilities(&self, mode: ProbabilityMode, counts: [u64; 4]) -> Probabilities {
        let kind = self.kind();
        let equal = Probabilities::equal(kind);
        let Some(fr) = Fractions::from_counts(counts, PROBE_PRIOR) else {
            return equal;
        };
        let fr = restrict(fr, kind);
        match mode {
            ProbabilityMode::Equal => equal,
            ProbabilityMode::Optimal => Probabilities::least_variance(&fr, kind, PROBE_FLOOR),
            ProbabilityMode::Cost => Probabilities::least_variance(&fr, kind, PROBE_FLOOR)
                .cost_heuristic(&fr, kind, PROBE_FLOOR),
        }
    }
}

/// `fr` without the ray types `kind` rules out (the prior gave them a share).
fn restrict(fr: Fractions, kind: ProxyKind) -> Fractions {
    let mut f = fr.f;
    match kind {
        ProxyKind::Outside => f[1] = 0.0,
        ProxyKind::Inside => f[2] = 0.0,
        ProxyKind::General => {}
    }
    let s: f64 = f.iter().sum();
    Fractions {
        f: f.map(|x| x / s),
    }
}

/// The face planes of `tris` when they bound a convex solid (every vertex on the inner side
/// of every non-degenerate face, within a relative tolerance), oriented so that the
/// vertices' centroid is inside; `None` otherwise or for more than 4096 triangles.
fn convex_planes(tris: &[[Vec3; 3]]) -> Option<Vec<(Vec3, f32)>> {
    if tris.is_empty() || tris.len() > 4096 {
        return None;
    }
    let centroid = tris.iter().flatten().copied().sum::<Vec3>() / (3 * tris.len()) as f32;
    let b = Bounds::of_triangles(tris);
    let tol = 1e-5 * (b.max - b.min).max_element().max(f32::MIN_POSITIVE);
    let mut planes = Vec::with_capacity(tris.len());
    for t in tris {
        let n = (t[1] - t[0]).cross(t[2] - t[0]);
        let len = n.length();
        if !(len > 0.0 && len.is_finite()) {
            continue;
        }
        let mut n = n / len;
        let mut d = n.dot(t[0]);
        if n.dot(centroid) > d {
            (n, d) = (-n, -d);
        }
        if tris.iter().flatten().any(|v| n.dot(*v) > d + tol) {
            return None;
        }
        planes.push((n, d));
    }
    Some(planes)
}

/// Where the ray `origin + t dir` (`t >= 0`) leaves box `b`, if it meets it.
fn exit(b: &Bounds, origin: Vec3, dir: Vec3) -> Option<f32> {
    if b.is_empty() {
        return None;
    }
    let inv = dir.recip();
    let t0 = (b.min - origin) * inv;
    let t1 = (b.max - origin) * inv;
    // NaN (0 · ∞ on a slab's plane) is dropped by min/max: the slab then does not bound.
    let near = t0.min(t1).max_element().max(0.0);
    let far = t0.max(t1).min_element();
    // A little beyond the exit: hits on the box's own faces count.
    let far = far * (1.0 + 1e-5) + 1e-6 * (b.max - b.min).max_element();
    (near <= far).then_some(far)
}

/// Whether the ray `p + t dir`, `t > 0`, crosses triangle `t` (Möller–Trumbore).
fn crosses(p: Vec3, dir: Vec3, t: &[Vec3; 3]) -> bool {
    let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
    let h = dir.cross(e2);
    let a = e1.dot(h);
    if a.abs() < 1e-12 {
        return false;
    }
    let f = 1.0 / a;
    let s = p - t[0];
    let u = f * s.dot(h);
    if !(0.0..=1.0).contains(&u) {
        return false;
    }
    let q = s.cross(e1);
    let v = f * dir.dot(q);
    if v < 0.0 || u + v > 1.0 {
        return false;
    }
    f * e2.dot(q) > 0.0
}
