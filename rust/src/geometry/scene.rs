//! A scene: a [`Mesh`], the BVH over it (built on first query), and traversal counters.
//! All batched queries validate every ray first and fail without side effects.
//!
//! Objects can be moved rigidly (any finite affine map) with
//! [`Scene::set_object_transform`]: the scene keeps each moved object's rest-pose
//! triangles and maps those, so a sequence of poses never accumulates rounding, and it
//! refits (or drops) the BVH.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::OnceLock;

use glam::{Affine3A, Vec3, Vec3A};
use obvhs::ploc::morton::morton_encode_u64;
use rayon::prelude::*;

use super::bvh::{BuildQuality, Bvh, BvhUpdate, OccluderHint, TraversalCounters, PACKET};
use super::mesh::{check_finite, triangle_cross, Bounds, Mesh};
use crate::bsdf::Material;
use crate::error::{Error, Result};
use crate::lights::area::AreaLight;
use crate::parallel::with_threads;

/// Rays traced per parallel work item; fixed so results never depend on the thread count.
const CHUNK: usize = 1024;

/// Shortest run of rays from one origin that [`Scene::occluded`] traces as a packet.
pub const MIN_PACKET: usize = 4;

/// Square of the least cosine between a packet's directions and their mean for
/// [`Scene::occluded`] to trace them together (45°): wider packets share few nodes, and
/// their rays go faster one by one.
const PACKET_COSINE_SQUARED: f32 = 0.5;

/// Smallest batch that [`Scene::occluded`] reorders by origin.
const SPATIAL_ORDER_MIN: usize = 1 << 16;

/// Least mean number of node visits per ray, over a sample of a batch, for
/// [`Scene::occluded`] to reorder it by origin.
const SPATIAL_ORDER_NODES: f64 = 6.0;

/// Whether `directions` (non-zero) lie within 45° of their sum (their mean direction when
/// they have one length, as record bundles' unit directions do). Squared, so that no
/// direction is normalised (the normalisations were a third of the batch driver's time on
/// record bundles): `d · m >= cos 45° |d| |m|` as `(d · m)² >= ½ |d|² |m|²` with
/// `d · m > 0`. It only chooses how rays are traced, never what they answer.
fn coherent(directions: &[Vec3A]) -> bool {
    let sum = directions.iter().sum::<Vec3A>();
    let sum_sq = sum.length_squared();
    sum_sq > 0.0
        && directions.iter().all(|d| {
            let along = d.dot(sum);
            along > 0.0 && along * along >= PACKET_COSINE_SQUARED * d.length_squared() * sum_sq
        })
}

/// How [`Scene::occluded`] traces a batch (see [`Scene::spatial_order`]).
#[derive(Debug, PartialEq)]
enum TraceOrder {
    /// In the order given.
    Given,
    /// Ray after ray in this order (a permutation of the batch).
    Rays(Vec<u32>),
    /// Run after run of rays from one origin (ranges of the batch), in this order.
    Runs(Vec<std::ops::Range<u32>>),
}

/// The runs of consecutive rays from one origin (compared bit for bit) in the order of
/// `key` of their origins (ties in the given order); None when the runs are in that order
/// already.
fn bundle_order(
    origins: &[[f32; 3]],
    key: impl Fn(&[f32; 3]) -> u64,
) -> Option<Vec<std::ops::Range<u32>>> {
    let bits = |o: &[f32; 3]| o.map(f32::to_bits);
    let mut runs: Vec<(u64, u32, u32)> = Vec::new();
    let mut start = 0;
    for i in 1..=origins.len() {
        if i == origins.len() || bits(&origins[i]) != bits(&origins[start]) {
            runs.push((key(&origins[start]), start as u32, i as u32));
            start = i;
        }
    }
    if runs.is_sorted() {
        return None;
    }
    runs.sort_unstable();
    Some(runs.into_iter().map(|(_, s, e)| s..e).collect())
}

/// [`occluded_chunk`] with counters on or off.
fn occluded_chunk_counting(
    counting: bool,
    bvh: &Bvh,
    rays: &RayBatch,
    base: usize,
    out: &mut [bool],
    counters: &mut TraversalCounters,
) {
    if counting {
        occluded_chunk::<true>(bvh, rays, base, out, counters);
    } else {
        occluded_chunk::<false>(bvh, rays, base, out, counters);
    }
}

/// [`Scene::occluded`] on rays `base..base + out.len()`.
fn occluded_chunk<const COUNT: bool>(
    bvh: &Bvh,
    rays: &RayBatch,
    base: usize,
    out: &mut [bool],
    counters: &mut TraversalCounters,
) {
    #[cfg(target_arch = "x86_64")]
    match crate::simd::level() {
        // SAFETY: the CPU has AVX-512 F and VL.
        crate::simd::SimdLevel::Avx512 => unsafe {
            return occluded_chunk_avx512::<COUNT>(bvh, rays, base, out, counters);
        },
        // SAFETY: the CPU has AVX2.
        crate::simd::SimdLevel::Avx2 => unsafe {
            return occluded_chunk_avx2::<COUNT>(bvh, rays, base, out, counters);
        },
        _ => {}
    }
    let trace = |o, d, t, hint: &mut _, c: &mut _| bvh.occluded_hinted::<COUNT>(o, d, t, hint, c);
    occluded_chunk_with::<COUNT>(bvh, rays, base, out, counters, trace);
}

/// [`occluded_chunk`] compiled for AVX2, with the single-ray traversal inlined into its
/// loop (one call and one instruction-set dispatch less per ray).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn occluded_chunk_avx2<const COUNT: bool>(
    bvh: &Bvh,
    rays: &RayBatch,
    base: usize,
    out: &mut [bool],
    counters: &mut TraversalCounters,
) {
    // Defined here to be compiled for AVX2 (closures take their function's features).
    let trace = |o, d, t, hint: &mut _, c: &mut _| bvh.hinted_avx2::<COUNT>(o, d, t, hint, c);
    occluded_chunk_with::<COUNT>(bvh, rays, base, out, counters, trace);
}

/// [`occluded_chunk_avx2`] for AVX-512 VL.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512vl")]
fn occluded_chunk_avx512<const COUNT: bool>(
    bvh: &Bvh,
    rays: &RayBatch,
    base: usize,
    out: &mut [bool],
    counters: &mut TraversalCounters,
) {
    // As in `occluded_chunk_avx2`.
    let trace = |o, d, t, hint: &mut _, c: &mut _| bvh.hinted_avx512::<COUNT>(o, d, t, hint, c);
    occluded_chunk_with::<COUNT>(bvh, rays, base, out, counters, trace);
}

/// The loop of [`occluded_chunk`], tracing single rays with `trace` (a form of
/// [`Bvh::occluded_hinted`]).
#[inline(always)]
fn occluded_chunk_with<const COUNT: bool>(
    bvh: &Bvh,
    rays: &RayBatch,
    base: usize,
    out: &mut [bool],
    counters: &mut TraversalCounters,
    trace: impl Fn(Vec3A, Vec3A, f32, &mut OccluderHint, &mut TraversalCounters) -> bool,
) {
    let origins = &rays.origins[base..base + out.len()];
    // Origins compared bit for bit (-0.0 and 0.0 would round apart), each read once.
    let bits = |k: usize| origins.get(k).map(|o| o.map(f32::to_bits));
    let mut hint = OccluderHint::NONE;
    let (mut k, mut next) = (0, bits(0));
    while let Some(origin) = next {
        let i = base + k;
        // A run of rays from one origin (up to a packet).
        let mut run = 1;
        next = bits(k + 1);
        while run < PACKET && next == Some(origin) {
            run += 1;
            next = bits(k + run);
        }
        let o = Vec3A::from(origins[k]);
        let direction = |l: usize| Vec3A::from(rays.directions[i + l]);
        let packet = (run >= MIN_PACKET)
            .then(|| std::array::from_fn::<_, PACKET, _>(|l| direction(l.min(run - 1))))
            .filter(|directions| coherent(&directions[..run]));
        if let Some(directions) = packet {
            let tmax: [f32; PACKET] = std::array::from_fn(|l| rays.tmax_of(i + l.min(run - 1)));
            let occluded = bvh.occluded_packet::<COUNT>(
                o,
                &directions[..run],
                &tmax[..run],
                &mut hint,
                counters,
            );
            for (l, slot) in out[k..k + run].iter_mut().enumerate() {
                *slot = occluded >> l & 1 != 0;
            }
        } else {
            // One by one: a run too short or too wide for a packet.
            for (l, slot) in out[k..k + run].iter_mut().enumerate() {
                *slot = trace(o, direction(l), rays.tmax_of(i + l), &mut hint, counters);
            }
        }
        // The hint carries over to the next run only when it shares the origin.
        if next != Some(origin) {
            hint = OccluderHint::NONE;
        }
        k += run;
    }
}

/// Upper ends of the ray segments of a batch.
#[derive(Clone, Copy, Debug)]
pub enum TMax<'a> {
    /// One value for every ray (may be `inf`).
    Scalar(f32),
    /// One value per ray.
    PerRay(&'a [f32]),
}

/// A batch of rays `origin + t direction`, `t` in `[0, tmax)`.
#[derive(Clone, Copy, Debug)]
pub struct RayBatch<'a> {
    pub origins: &'a [[f32; 3]],
    pub directions: &'a [[f32; 3]],
    pub tmax: TMax<'a>,
}

impl<'a> RayBatch<'a> {
    /// Rays with an unbounded segment.
    pub fn new(origins: &'a [[f32; 3]], directions: &'a [[f32; 3]]) -> Self {
        Self {
            origins,
            directions,
            tmax: TMax::Scalar(f32::INFINITY),
        }
    }

    /// Number of rays.
    pub fn len(&self) -> usize {
        self.origins.len()
    }

    /// True for a batch of no rays.
    pub fn is_empty(&self) -> bool {
        self.origins.is_empty()
    }

    #[inline(always)]
    fn tmax_of(&self, i: usize) -> f32 {
        match self.tmax {
            TMax::Scalar(t) => t,
            TMax::PerRay(t) => t[i],
        }
    }

    /// Checks lengths, finiteness, non-zero directions and `tmax >= 0` (NaN rejected).
    /// Costs a few percent of tracing the batch: fixed chunks are scanned in parallel with
    /// a branch-free test and only a failing chunk is searched for its first bad row.
    pub fn validate(&self) -> Result<()> {
        self.validate_shape()?;
        let first = first_where(self.origins, bad_origin)
            .map(|i| (BadArgument::Origins, i))
            .or_else(|| {
                first_where(self.directions, bad_direction).map(|i| (BadArgument::Directions, i))
            })
            .or_else(|| match self.tmax {
                TMax::PerRay(t) => first_where(t, |v| bad_tmax(*v)).map(|i| (BadArgument::Tmax, i)),
                TMax::Scalar(_) => None,
            });
        first.map_or(Ok(()), |bad| Err(self.error_at(bad)))
    }

    /// The checks of [`Self::validate`] that do not read the rays: as many directions and
    /// `tmax` values (when not one for all) as origins, and a valid scalar `tmax`.
    pub fn validate_shape(&self) -> Result<()> {
        let n = self.origins.len();
        if self.directions.len() != n {
            return Err(Error::invalid(
                "directions",
                format!("has {} rows but origins has {n}", self.directions.len()),
            ));
        }
        match self.tmax {
            TMax::Scalar(t) if bad_tmax(t) => {
                Err(Error::invalid("tmax", format!("must be >= 0, got {t}")))
            }
            TMax::PerRay(t) if t.len() != n => Err(Error::invalid(
                "tmax",
                format!("has {} values but there are {n} rays", t.len()),
            )),
            _ => Ok(()),
        }
    }

    /// The first bad row among rays `range` (of a batch whose shape
    /// [`Self::validate_shape`] accepted), as [`Self::validate`] orders them: origins, then
    /// directions, then `tmax`. The least over ranges is the batch's first.
    #[inline]
    pub fn first_bad(&self, range: std::ops::Range<usize>) -> Option<(BadArgument, usize)> {
        let at = |argument| move |i| (argument, range.start + i);
        first_in(&self.origins[range.clone()], bad_origin)
            .map(at(BadArgument::Origins))
            .or_else(|| {
                first_in(&self.directions[range.clone()], bad_direction)
                    .map(at(BadArgument::Directions))
            })
            .or_else(|| match self.tmax {
                TMax::PerRay(t) => {
                    first_in(&t[range.clone()], |v| bad_tmax(*v)).map(at(BadArgument::Tmax))
                }
                TMax::Scalar(_) => None,
            })
    }

    /// The error for a bad row.
    pub fn error_at(&self, (argument, i): (BadArgument, usize)) -> Error {
        match (argument, self.tmax) {
            (BadArgument::Origins, _) => Error::invalid(
                "origins",
                format!("row {i} is not finite: {:?}", self.origins[i]),
            ),
            (BadArgument::Directions, _) => Error::invalid(
                "directions",
                format!(
                    "row {i} must be finite and non-zero, got {:?}",
                    self.directions[i]
                ),
            ),
            (BadArgument::Tmax, TMax::PerRay(t)) => {
                Error::invalid("tmax", format!("value {i} must be >= 0, got {}", t[i]))
            }
            (BadArgument::Tmax, TMax::Scalar(t)) => {
                Error::invalid("tmax", format!("must be >= 0, got {t}"))
            }
        }
    }
}

/// The argument of a [`RayBatch`] that holds a bad row, in the order errors are reported.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum BadArgument {
    Origins,
    Directions,
    Tmax,
}

/// An origin with a non-finite coordinate (branch-free).
#[inline(always)]
fn bad_origin(r: &[f32; 3]) -> bool {
    !(r[0].is_finite() & r[1].is_finite() & r[2].is_finite())
}

/// A direction with a non-finite coordinate or of zero length (branch-free).
#[inline(always)]
fn bad_direction(r: &[f32; 3]) -> bool {
    bad_origin(r) | ((r[0] == 0.0) & (r[1] == 0.0) & (r[2] == 0.0))
}

/// A segment end that is NaN or negative.
#[inline(always)]
fn bad_tmax(t: f32) -> bool {
    t.is_nan() | (t < 0.0)
}

/// Index of the first item for which `bad` holds: a branch-free pass, and a search only
/// when it finds one.
#[inline]
fn first_in<T>(items: &[T], bad: impl Fn(&T) -> bool) -> Option<usize> {
    let any = items.iter().fold(false, |acc, x| acc | bad(x));
    if any {
        items.iter().position(bad)
    } else {
        None
    }
}

/// [`first_in`] over fixed chunks scanned in parallel.
fn first_where<T: Sync>(items: &[T], bad: impl Fn(&T) -> bool + Sync) -> Option<usize> {
    const SCAN: usize = 16 * 1024;
    items
        .par_chunks(SCAN)
        .enumerate()
        .find_map_first(|(c, chunk)| first_in(chunk, &bad).map(|i| c * SCAN + i))
}

/// Closest hits of a batch, one entry per ray. Misses have `t = inf`, `prim = obj = -1`,
/// `u = v = 0` and NaN position and normal.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Hits {
    pub t: Vec<f32>,
    pub prim: Vec<i32>,
    pub obj: Vec<i32>,
    pub u: Vec<f32>,
    pub v: Vec<f32>,
    /// Hit point from the barycentrics (lies on the triangle).
    pub position: Vec<[f32; 3]>,
    /// Unit geometric normal, `(v1 - v0) x (v2 - v0)` normalised: not flipped toward the ray.
    pub normal: Vec<[f32; 3]>,
}

/// One ray's closest hit in world terms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceHit {
    pub t: f32,
    pub prim: u32,
    pub obj: u32,
    pub u: f32,
    pub v: f32,
    pub position: Vec3,
    pub normal: Vec3,
}

#[derive(Default, Debug)]
struct AtomicCounters {
    rays: AtomicU64,
    nodes: AtomicU64,
    triangles: AtomicU64,
}

/// Triangles, objects and the acceleration structure over them.
#[derive(Debug)]
pub struct Scene {
    mesh: Mesh,
    lights: Vec<AreaLight>,
    bounds: Bounds,
    /// Bounds of the objects that were never moved, so that moving one costs time in its
    /// own size only.
    still_bounds: Bounds,
    quality: BuildQuality,
    bvh: OnceLock<Bvh>,
    /// [`Scene::geometry_fingerprint`], computed on first use.
    fingerprint: OnceLock<u64>,
    counting: AtomicBool,
    counters: AtomicCounters,
    /// Objects moved by [`Scene::set_object_transform`]: rest-pose triangles and the
    /// current transform.
    posed: BTreeMap<u32, Posed>,
}

/// A moved object's rest pose and the transform applied to it.
#[derive(Clone, Debug)]
struct Posed {
    rest: Vec<[Vec3; 3]>,
    transform: Affine3A,
    /// Bounds of the object as it is now.
    bounds: Bounds,
}

impl Default for Scene {
    fn default() -> Self {
        Self::from_mesh(Mesh::new())
    }
}

impl Clone for Scene {
    /// Clones geometry and settings; the BVH is shared work and is cloned too, counters
    /// start at zero.
    fn clone(&self) -> Self {
        let s = Self {
            mesh: self.mesh.clone(),
            lights: self.lights.clone(),
            bounds: self.bounds,
            still_bounds: self.still_bounds,
            quality: self.quality,
            bvh: OnceLock::new(),
            fingerprint: self.fingerprint.clone(),
            counting: AtomicBool::new(self.counting_enabled()),
            counters: AtomicCounters::default(),
            posed: self.posed.clone(),
        };
        if let Some(b) = self.bvh.get() {
            let _ = s.bvh.set(b.clone());
        }
        s
    }
}

impl Scene {
    /// An empty scene.
    pub fn new() -> Self {
        Self::default()
    }

    /// A scene over an existing mesh; counters are on.
    pub fn from_mesh(mesh: Mesh) -> Self {
        Self {
            bounds: mesh.bounds(),
            still_bounds: mesh.bounds(),
            mesh,
            lights: Vec::new(),
            quality: BuildQuality::default(),
            bvh: OnceLock::new(),
            fingerprint: OnceLock::new(),
            counting: AtomicBool::new(true),
            counters: AtomicCounters::default(),
            posed: BTreeMap::new(),
        }
    }

    /// The geometry.
    pub fn mesh(&self) -> &Mesh {
        &self.mesh
    }

    /// Number of triangles, degenerate ones included.
    pub fn num_triangles(&self) -> usize {
        self.mesh.triangles.len()
    }

    /// Number of objects.
    pub fn num_objects(&self) -> usize {
        self.mesh.objects.len()
    }

    /// Bounds of all vertices (kept up to date as geometry is added).
    pub fn bounds(&self) -> Bounds {
        self.bounds
    }

    /// Adds an indexed mesh as a new object (see [`Mesh::add_indexed`]); drops the BVH.
    pub fn add_indexed(
        &mut self,
        vertices: &[[f32; 3]],
        faces: &[[i64; 3]],
        material: Material,
        name: Option<String>,
    ) -> Result<u32> {
        let id = self.mesh.add_indexed(vertices, faces, material, name)?;
        self.geometry_changed();
        Ok(id)
    }

    /// Appends every object of `mesh`; drops the BVH.
    pub fn append(&mut self, mesh: &Mesh) {
        self.mesh.append(mesh);
        self.geometry_changed();
    }

    fn geometry_changed(&mut self) {
        self.bounds = self.mesh.bounds();
        self.still_bounds = self.bounds_of_still_objects();
        self.bvh = OnceLock::new();
        self.fingerprint = OnceLock::new();
    }

    /// A 64-bit digest of the scene's geometry at rest: every object's triangle count and
    /// vertices as added, before any [`Scene::set_object_transform`] (so an animated scene
    /// keeps its fingerprint from frame to frame). Visibility caches record the scene they
    /// were built for by it and refuse another. Computed once per change of geometry.
    pub fn geometry_fingerprint(&self) -> u64 {
        *self.fingerprint.get_or_init(|| {
            // FxHash-style mixing of 64-bit words, then the splitmix64 finaliser: not
            // cryptographic, but any edit of a vertex or a count changes it.
            let mut h = 0u64;
            let mut word = |w: u64| h = (h.rotate_left(5) ^ w).wrapping_mul(0x517c_c1b7_2722_0a95);
            word(self.mesh.objects.len() as u64);
            for i in 0..self.mesh.objects.len() {
                let triangles = match self.posed.get(&(i as u32)) {
                    Some(p) => &p.rest[..],
                    None => self.triangles_of(i),
                };
                word(triangles.len() as u64);
                for v in triangles.iter().flatten() {
                    word(v.x.to_bits() as u64 | (v.y.to_bits() as u64) << 32);
                    word(v.z.to_bits() as u64);
                }
            }
            let mut z = h ^ (h >> 30);
            z = z.wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            z ^ (z >> 31)
        })
    }

    /// The triangles of object `i` (which must exist).
    fn triangles_of(&self, i: usize) -> &[[Vec3; 3]] {
        let o = &self.mesh.objects[i];
        let first = o.first_triangle as usize;
        &self.mesh.triangles[first..first + o.num_triangles as usize]
    }

    /// Bounds of the objects not in `posed` (all of the mesh when none moved).
    fn bounds_of_still_objects(&self) -> Bounds {
        if self.posed.is_empty() {
            return self.bounds;
        }
        (0..self.mesh.objects.len())
            .filter(|i| !self.posed.contains_key(&(*i as u32)))
            .fold(Bounds::EMPTY, |b, i| {
                b.union(&Bounds::of_triangles(self.triangles_of(i)))
            })
    }

    /// Builds the BVH now with the given preset (on the current rayon pool).
    pub fn build(&mut self, quality: BuildQuality) -> &Bvh {
        self.quality = quality;
        self.bvh = OnceLock::new();
        self.bvh()
    }

    /// The BVH, built with the scene's preset on first use. Objects that have been moved
    /// ([`Scene::set_object_transform`]) get subtrees of their own
    /// ([`Bvh::build_grouped`]), so that refits after they move keep the tree's quality.
    pub fn bvh(&self) -> &Bvh {
        self.bvh
            .get_or_init(|| Bvh::build_grouped(&self.mesh, self.quality, &self.posed_ranges()))
    }

    /// Triangle ranges of the moved objects, by object id.
    fn posed_ranges(&self) -> Vec<std::ops::Range<usize>> {
        self.posed
            .keys()
            .map(|&o| {
                let o = &self.mesh.objects[o as usize];
                o.first_triangle as usize..(o.first_triangle + o.num_triangles) as usize
            })
            .collect()
    }

    /// True once the BVH exists.
    pub fn is_built(&self) -> bool {
        self.bvh.get().is_some()
    }

    /// Whether queries update the counters (on by default; see benches for the cost).
    pub fn counting_enabled(&self) -> bool {
        self.counting.load(Ordering::Relaxed)
    }

    /// Switches counting on or off.
    pub fn set_counting(&self, on: bool) {
        self.counting.store(on, Ordering::Relaxed);
    }

    /// Totals since the last reset.
    pub fn counters(&self) -> TraversalCounters {
        TraversalCounters {
            rays: self.counters.rays.load(Ordering::Relaxed),
            nodes: self.counters.nodes.load(Ordering::Relaxed),
            triangles: self.counters.triangles.load(Ordering::Relaxed),
        }
    }

    /// Sets all counters to zero.
    pub fn reset_counters(&self) {
        self.counters.rays.store(0, Ordering::Relaxed);
        self.counters.nodes.store(0, Ordering::Relaxed);
        self.counters.triangles.store(0, Ordering::Relaxed);
    }

    /// Adds a chunk's local counts to the totals.
    pub fn add_counters(&self, c: TraversalCounters) {
        self.counters.rays.fetch_add(c.rays, Ordering::Relaxed);
        self.counters.nodes.fetch_add(c.nodes, Ordering::Relaxed);
        self.counters
            .triangles
            .fetch_add(c.triangles, Ordering::Relaxed);
    }

    /// Offset for spawning rays off a surface at `p` when its triangle is not known: 64
    /// ulps of `|p|`, plus 2 ulps of the scene's size and distance from the origin, so it
    /// clears the rounding of a hit point interpolated on any triangle of the scene (whose
    /// vertices are at most that far out) at any scene scale. A scene of mixed scales (a
    /// kilometre of ground beside centimetre parts) then offsets by a few parts in 1e7 of
    /// its size; [`Self::hit_epsilon`], which knows the triangle, offsets by less.
    pub fn ray_epsilon(&self, p: Vec3) -> f32 {
        let b = self.bounds();
        (p.abs().max_element() + (b.extent() + b.max_abs()) * 2f32.powi(-5)) * 2f32.powi(-17)
    }

    /// Moves `p` off the surface along `n` (which should face the side rays leave toward).
    pub fn offset_point(&self, p: Vec3, n: Vec3) -> Vec3 {
        p + n * self.ray_epsilon(p)
    }

    /// Offset for spawning rays off `hit`: 64 ulps of the largest coordinate of its
    /// triangle's vertices, which bounds the rounding of its interpolated position whatever
    /// the rest of the scene's scale.
    pub fn hit_epsilon(&self, hit: &SurfaceHit) -> f32 {
        let tri = &self.mesh.triangles[hit.prim as usize];
        let m = tri[0]
            .abs()
            .max(tri[1].abs())
            .max(tri[2].abs())
            .max(hit.position.abs())
            .max_element();
        m * 2f32.powi(-17)
    }

    /// Moves `hit`'s position off its surface along `n` by [`Self::hit_epsilon`].
    pub fn offset_hit(&self, hit: &SurfaceHit, n: Vec3) -> Vec3 {
        hit.position + n * self.hit_epsilon(hit)
    }

    /// Shadow query for one ray; counts it if counting is on. `direction` must be non-zero.
    #[inline]
    pub fn occluded1(
        &self,
        origin: Vec3,
        direction: Vec3,
        tmax: f32,
        c: &mut TraversalCounters,
    ) -> bool {
        let bvh = self.bvh();
        if self.counting_enabled() {
            bvh.occluded::<true>(origin.into(), direction.into(), tmax, c)
        } else {
            bvh.occluded::<false>(origin.into(), direction.into(), tmax, c)
        }
    }

    /// Closest-hit query for one ray; counts it if counting is on.
    #[inline]
    pub fn intersect1(
        &self,
        origin: Vec3,
        direction: Vec3,
        tmax: f32,
        c: &mut TraversalCounters,
    ) -> Option<SurfaceHit> {
        let bvh = self.bvh();
        let hit = if self.counting_enabled() {
            bvh.intersect::<true>(origin.into(), direction.into(), tmax, c)
        } else {
            bvh.intersect::<false>(origin.into(), direction.into(), tmax, c)
        }?;
        let tri = &self.mesh.triangles[hit.triangle as usize];
        let w = 1.0 - hit.u - hit.v;
        Some(SurfaceHit {
            t: hit.t,
            prim: hit.triangle,
            obj: self.mesh.object_ids[hit.triangle as usize],
            u: hit.u,
            v: hit.v,
            position: tri[0] * w + tri[1] * hit.u + tri[2] * hit.v,
            normal: triangle_cross(tri).normalize(),
        })
    }

    /// Runs `per_ray` over `n` rays in fixed chunks on `threads` workers, collecting the
    /// results in order and adding the chunks' counters to the scene's.
    pub fn map_rays<T: Send + Copy + Default>(
        &self,
        n: usize,
        threads: Option<usize>,
        per_ray: impl Fn(usize, &mut TraversalCounters) -> T + Sync,
    ) -> Result<Vec<T>> {
        self.map_chunks(n, threads, |base, chunk, counters| {
            for (k, slot) in chunk.iter_mut().enumerate() {
                *slot = per_ray(base + k, counters);
            }
        })
    }

    /// Fills the results of `n` rays chunk by chunk on `threads` workers: `per_chunk(base,
    /// out, counters)` answers rays `base..base + out.len()`. Chunks are fixed, so results
    /// never depend on the thread count; their counters are added to the scene's.
    pub fn map_chunks<T: Send + Copy + Default>(
        &self,
        n: usize,
        threads: Option<usize>,
        per_chunk: impl Fn(usize, &mut [T], &mut TraversalCounters) + Sync,
    ) -> Result<Vec<T>> {
        let all = |base, out: &mut [T], c: &mut _| -> std::result::Result<(), ()> {
            per_chunk(base, out, c);
            Ok(())
        };
        Ok(self.try_map_chunks(n, threads, all)?.unwrap_or_default())
    }

    /// [`Self::map_chunks`] whose chunks may refuse their rays: `per_chunk` returns the
    /// reason, and the least reason over the refusing chunks (whichever threads ran them)
    /// is returned instead of the results. Counters are added only when no chunk refused.
    fn try_map_chunks<T: Send + Copy + Default, E: Ord + Send>(
        &self,
        n: usize,
        threads: Option<usize>,
        per_chunk: impl Fn(usize, &mut [T], &mut TraversalCounters) -> std::result::Result<(), E> + Sync,
    ) -> Result<std::result::Result<Vec<T>, E>> {
        with_threads(threads, || {
            self.bvh();
            let mut out = vec![T::default(); n];
            let (counters, refused) = out
                .par_chunks_mut(CHUNK)
                .enumerate()
                .map(|(c, chunk)| {
                    let mut counters = TraversalCounters::default();
                    let refused = per_chunk(c * CHUNK, chunk, &mut counters).err();
                    (counters, refused)
                })
                .reduce(
                    || (TraversalCounters::default(), None),
                    |(mut a, ra), (b, rb)| {
                        a += b;
                        (a, ra.into_iter().chain(rb).min())
                    },
                );
            match refused {
                Some(reason) => Err(reason),
                None => {
                    self.add_counters(counters);
                    Ok(out)
                }
            }
        })
    }

    /// Shadow queries: `true` where something lies on the segment. Runs of at least
    /// [`MIN_PACKET`] consecutive rays from one origin (record bundles) are traced in
    /// packets ([`Bvh::occluded_packet`]); other rays one by one, first trying the previous
    /// ray's occluder when it shared their origin. The answers are the same either way.
    ///
    /// Large batches of scattered rays in trees larger than a core's L2 cache, whose rays
    /// visit many nodes (judged on every 256th ray), are traced in the Morton order of their
    /// origins and answered in the given order: consecutive rays then reuse the same
    /// nodes and triangles from cache (garden's incoherent shadow rays about 2x). The order
    /// depends only on the rays, so answers and counters are the same for any thread
    /// count; the sample that decides is not counted.
    pub fn occluded(&self, rays: &RayBatch, threads: Option<usize>) -> Result<Vec<bool>> {
        rays.validate_shape()?;
        if self.may_reorder(rays) {
            rays.validate()?;
            match with_threads(threads, || self.spatial_order(rays))? {
                TraceOrder::Rays(order) => return self.occluded_in_order(rays, &order, threads),
                TraceOrder::Runs(runs) => return self.occluded_by_runs(rays, &runs, threads),
                TraceOrder::Given => {}
            }
        }
        self.occluded_as_given(rays, threads)
    }

    /// [`Scene::occluded`] on rays of checked lengths, traced in the order given. Each
    /// chunk validates its rays before tracing them, while they are in cache (a separate
    /// pass over the batch cost 3% of cornell's incoherent shadow rays on two threads);
    /// counters are added only when every ray is valid.
    fn occluded_as_given(&self, rays: &RayBatch, threads: Option<usize>) -> Result<Vec<bool>> {
        let counting = self.counting_enabled();
        self.try_map_chunks(rays.len(), threads, |base, out, counters| {
            if let Some(bad) = rays.first_bad(base..base + out.len()) {
                return Err(bad);
            }
            let bvh = self.bvh();
            occluded_chunk_counting(counting, bvh, rays, base, out, counters);
            Ok(())
        })?
        .map_err(|bad| rays.error_at(bad))
    }

    /// Whether [`Self::spatial_order`] may reorder `rays`: a large batch in a tree larger
    /// than L2.
    fn may_reorder(&self, rays: &RayBatch) -> bool {
        rays.len() >= SPATIAL_ORDER_MIN && self.bvh().outgrows_l2()
    }

    /// An order of the rays (valid ones) in which consecutive ones start near each other
    /// (Morton order of their origins; ties in the given order), for large trees and large
    /// batches whose rays visit many nodes; [`TraceOrder::Given`] where tracing in the
    /// given order is as good. Runs of rays from one origin (record bundles) are coherent
    /// already and stay whole: the runs are ordered by their origins instead, so that
    /// consecutive bundles start near each other and share the nodes and blades they read;
    /// runs already in that order are left as given.
    fn spatial_order(&self, rays: &RayBatch) -> TraceOrder {
        let n = rays.len();
        let bvh = self.bvh();
        if !self.may_reorder(rays) {
            return TraceOrder::Given;
        }
        let repeated = rays
            .origins
            .windows(2)
            .step_by(61)
            .filter(|w| w[0] == w[1])
            .count();
        let bundles = repeated * 2 > n.div_ceil(61);
        // Rays that leave the tree after a node or two (a small object under an open sky)
        // gain nothing: trace a sample of every 256th ray and reorder only when rays visit
        // many nodes, as they do in dense geometry that waits on memory.
        let sample = (0..n)
            .into_par_iter()
            .step_by(256)
            .map(|i| {
                let mut c = TraversalCounters::default();
                bvh.occluded::<true>(
                    Vec3A::from(rays.origins[i]),
                    Vec3A::from(rays.directions[i]),
                    rays.tmax_of(i),
                    &mut c,
                );
                c
            })
            .reduce(TraversalCounters::default, |mut a, b| {
                a += b;
                a
            });
        if (sample.nodes as f64) < SPATIAL_ORDER_NODES * sample.rays as f64 {
            return TraceOrder::Given;
        }
        let b = self.bounds();
        let top = (1 << 21) as f32 - 1.0;
        let scale = Vec3::splat(top) / (b.max - b.min).max(Vec3::splat(1e-30));
        let key = |o: &[f32; 3]| {
            let q = ((Vec3::from(*o) - b.min) * scale).clamp(Vec3::ZERO, Vec3::splat(top));
            morton_encode_u64(q.x as u32, q.y as u32, q.z as u32)
        };
        if bundles {
            return bundle_order(rays.origins, key).map_or(TraceOrder::Given, TraceOrder::Runs);
        }
        let mut keyed: Vec<(u64, u32)> = rays
            .origins
            .par_iter()
            .enumerate()
            .map(|(i, o)| (key(o), i as u32))
            .collect();
        keyed.par_sort_unstable();
        TraceOrder::Rays(keyed.into_iter().map(|(_, i)| i).collect())
    }

    /// [`Scene::occluded`] on valid rays traced run after run in the order of `runs`
    /// (ranges of the batch that together cover it once) and answered in the given order.
    /// The runs are read where they lie, not copied into a reordered batch (the copy cost
    /// as much as the order gained on garden's bundles). Work items are consecutive runs
    /// of at least [`CHUNK`] rays together, fixed by the runs alone, so answers and
    /// counters are the same for any thread count.
    fn occluded_by_runs(
        &self,
        rays: &RayBatch,
        runs: &[std::ops::Range<u32>],
        threads: Option<usize>,
    ) -> Result<Vec<bool>> {
        let mut items = Vec::new();
        let (mut first, mut size) = (0, 0);
        for (k, run) in runs.iter().enumerate() {
            size += run.len();
            if size >= CHUNK || k + 1 == runs.len() {
                items.push(first..k + 1);
                (first, size) = (k + 1, 0);
            }
        }
        let counting = self.counting_enabled();
        let bvh = self.bvh();
        with_threads(threads, || {
            let traced: Vec<(Vec<bool>, TraversalCounters)> = items
                .par_iter()
                .map(|item| {
                    let runs = &runs[item.clone()];
                    let mut out = vec![false; runs.iter().map(|r| r.len()).sum()];
                    let mut counters = TraversalCounters::default();
                    let mut k = 0;
                    for run in runs {
                        let (base, slots) = (run.start as usize, &mut out[k..k + run.len()]);
                        occluded_chunk_counting(counting, bvh, rays, base, slots, &mut counters);
                        k += run.len();
                    }
                    (out, counters)
                })
                .collect();
            let mut out = vec![false; rays.len()];
            let mut counters = TraversalCounters::default();
            for (item, (answers, c)) in items.into_iter().zip(traced) {
                counters += c;
                let mut k = 0;
                for run in &runs[item] {
                    let r = run.start as usize..run.end as usize;
                    out[r].copy_from_slice(&answers[k..k + run.len()]);
                    k += run.len();
                }
            }
            self.add_counters(counters);
            out
        })
    }

    /// [`Scene::occluded`] traced in `order` (a permutation of the rays), answered in the
    /// given order.
    fn occluded_in_order(
        &self,
        rays: &RayBatch,
        order: &[u32],
        threads: Option<usize>,
    ) -> Result<Vec<bool>> {
        let origins: Vec<[f32; 3]> = order.iter().map(|&i| rays.origins[i as usize]).collect();
        let directions: Vec<[f32; 3]> =
            order.iter().map(|&i| rays.directions[i as usize]).collect();
        let per_ray: Vec<f32>;
        let tmax = match rays.tmax {
            TMax::Scalar(t) => TMax::Scalar(t),
            TMax::PerRay(t) => {
                per_ray = order.iter().map(|&i| t[i as usize]).collect();
                TMax::PerRay(&per_ray)
            }
        };
        let sorted = RayBatch {
            origins: &origins,
            directions: &directions,
            tmax,
        };
        let answers = self.occluded_as_given(&sorted, threads)?;
        let mut out = vec![false; rays.len()];
        for (&i, a) in order.iter().zip(answers) {
            out[i as usize] = a;
        }
        Ok(out)
    }

    /// Closest hits.
    pub fn intersect(&self, rays: &RayBatch, threads: Option<usize>) -> Result<Hits> {
        rays.validate()?;
        let found = self.map_rays(rays.len(), threads, |i, c| {
            let o = Vec3::from(rays.origins[i]);
            let d = Vec3::from(rays.directions[i]);
            self.intersect1(o, d, rays.tmax_of(i), c)
        })?;
        let n = found.len();
        let mut hits = Hits {
            t: Vec::with_capacity(n),
            prim: Vec::with_capacity(n),
            obj: Vec::with_capacity(n),
            u: Vec::with_capacity(n),
            v: Vec::with_capacity(n),
            position: Vec::with_capacity(n),
            normal: Vec::with_capacity(n),
        };
        for h in found {
            let (t, prim, obj, u, v, p, nrm) = match h {
                Some(h) => (
                    h.t,
                    h.prim as i32,
                    h.obj as i32,
                    h.u,
                    h.v,
                    h.position,
                    h.normal,
                ),
                None => (f32::INFINITY, -1, -1, 0.0, 0.0, Vec3::NAN, Vec3::NAN),
            };
            hits.t.push(t);
            hits.prim.push(prim);
            hits.obj.push(obj);
            hits.u.push(u);
            hits.v.push(v);
            hits.position.push(p.into());
            hits.normal.push(nrm.into());
        }
        Ok(hits)
    }
}

/// Rigid motion of objects (animation).
impl Scene {
    /// Object `object`, or an error naming `object`.
    fn object(&self, object: u32) -> Result<&super::Object> {
        self.mesh.objects.get(object as usize).ok_or_else(|| {
            Error::invalid(
                "object",
                format!("no object {object} in a scene of {}", self.num_objects()),
            )
        })
    }

    /// Places object `object` at `transform` applied to its rest pose (its triangles as
    /// they were before the first call), and refits a built BVH ([`BvhUpdate::Refit`]).
    /// The identity restores the rest pose bit for bit. See
    /// [`Scene::set_object_transform_with`].
    pub fn set_object_transform(&mut self, object: u32, transform: Affine3A) -> Result<()> {
        self.set_object_transform_with(object, transform, BvhUpdate::Refit)
    }

    /// [`Scene::set_object_transform`] with the BVH update chosen by `update`. The first
    /// move of an object drops the BVH whatever `update` says: the next build gives the
    /// object a subtree of its own ([`Scene::bvh`]), which later refits keep as good as a
    /// rebuild. A refit that cannot match a rebuild (a triangle becomes degenerate or stops
    /// being so, say) falls back to a rebuild. Bounds, and the object's area light if it
    /// emits, follow the object. An unknown `object` or a non-finite `transform`, or one
    /// that maps a vertex out of the `f32` range, is an error naming the argument, and the
    /// scene is unchanged.
    pub fn set_object_transform_with(
        &mut self,
        object: u32,
        transform: Affine3A,
        update: BvhUpdate,
    ) -> Result<()> {
        let obj = self.object(object)?;
        let range = obj.first_triangle as usize..(obj.first_triangle + obj.num_triangles) as usize;
        if !transform.is_finite() {
            return Err(Error::invalid(
                "transform",
                format!("must be finite, got {transform:?}"),
            ));
        }
        let rest = match self.posed.get(&object) {
            Some(p) => &p.rest[..],
            None => &self.mesh.triangles[range.clone()],
        };
        let moved: Vec<[Vec3; 3]> = rest
            .iter()
            .map(|t| t.map(|v| transform.transform_point3(v)))
            .collect();
        if moved.iter().flatten().any(|v| !v.is_finite()) {
            return Err(Error::invalid(
                "transform",
                format!("maps vertices of object {object} out of the f32 range"),
            ));
        }
        let light = match self.lights.iter().position(|l| l.object == object) {
            Some(i) => {
                let radiance = self.lights[i].radiance().to_array();
                let light = AreaLight::new(object, moved.clone(), radiance).map_err(|e| {
                    Error::invalid("transform", format!("leaves the area light unusable: {e}"))
                })?;
                Some((i, light))
            }
            None => None,
        };
        // Validated: from here on nothing fails.
        if let Some((i, light)) = light {
            self.lights[i] = light;
        }
        let first_move = !self.posed.contains_key(&object);
        if first_move {
            let rest = self.mesh.triangles[range.clone()].to_vec();
            let bounds = Bounds::of_triangles(&rest);
            let posed = Posed {
                rest,
                transform: Affine3A::IDENTITY,
                bounds,
            };
            self.posed.insert(object, posed);
            self.still_bounds = self.bounds_of_still_objects();
        }
        let posed = self.posed.get_mut(&object).expect("inserted above");
        posed.transform = transform;
        posed.bounds = Bounds::of_triangles(&moved);
        self.mesh.triangles[range.clone()].copy_from_slice(&moved);
        self.bounds = (self.posed.values()).fold(self.still_bounds, |b, p| b.union(&p.bounds));
        match update {
            BvhUpdate::Refit if !first_move => {
                let refit = match self.bvh.get_mut() {
                    Some(bvh) => bvh.refit(&self.mesh, range),
                    None => true,
                };
                if !refit {
                    self.bvh = OnceLock::new();
                    self.bvh();
                }
            }
            _ => self.bvh = OnceLock::new(),
        }
        Ok(())
    }

    /// True once object `object` has been given a transform (false for unknown objects).
    pub fn is_posed(&self, object: u32) -> bool {
        self.posed.contains_key(&object)
    }

    /// The transform last given to object `object` (the identity if it never moved).
    pub fn object_transform(&self, object: u32) -> Result<Affine3A> {
        self.object(object)?;
        Ok(self
            .posed
            .get(&object)
            .map_or(Affine3A::IDENTITY, |p| p.transform))
    }

    /// Bounds of object `object`'s vertices as it is now (empty for an empty object).
    pub fn object_bounds(&self, object: u32) -> Result<Bounds> {
        self.object(object)?;
        Ok(match self.posed.get(&object) {
            Some(p) => p.bounds,
            None => Bounds::of_triangles(self.triangles_of(object as usize)),
        })
    }
}

/// Area lights. Emitters are objects of the mesh (they occlude and can be hit like any
/// other geometry); the scene keeps the [`AreaLight`] of each.
impl Scene {
    /// Adds a one-sided emitter over a triangle (3 vertices) or a quad (4 vertices, in order
    /// around its border) as a new, black object; it emits on the side of the winding normal
    /// `(v1 - v0) x (v2 - v0)`. Returns the object id. On error the scene is unchanged.
    pub fn add_area_light(
        &mut self,
        vertices: &[[f32; 3]],
        radiance: [f32; 3],
        name: Option<String>,
    ) -> Result<u32> {
        let faces: &[[i64; 3]] = match vertices.len() {
            3 => &[[0, 1, 2]],
            4 => &[[0, 1, 2], [0, 2, 3]],
            n => {
                return Err(Error::invalid(
                    "vertices",
                    format!("an area light is a triangle (3 vertices) or a quad (4), got {n}"),
                ))
            }
        };
        check_finite("vertices", vertices)?;
        let triangles = faces
            .iter()
            .map(|f| f.map(|i| Vec3::from_array(vertices[i as usize])))
            .collect();
        let object = self.num_objects() as u32;
        let light = AreaLight::new(object, triangles, radiance)?;
        let black = Material::Lambert { albedo: [0.0; 3] };
        let name = name.or_else(|| Some(format!("area_light{}", self.lights.len())));
        let id = self.add_indexed(vertices, faces, black, name)?;
        debug_assert_eq!(id, object);
        self.lights.push(light);
        Ok(id)
    }

    /// Makes the existing object `object` emit `radiance` from the winding side of its
    /// triangles (e.g. a lamp modelled as geometry). Fails if it already emits.
    pub fn set_emitter(&mut self, object: u32, radiance: [f32; 3]) -> Result<()> {
        let obj = self.object(object)?;
        if self.emitter(object).is_some() {
            return Err(Error::invalid(
                "object",
                format!("object {object} already emits"),
            ));
        }
        let first = obj.first_triangle as usize;
        let triangles = self.mesh.triangles[first..first + obj.num_triangles as usize].to_vec();
        self.lights
            .push(AreaLight::new(object, triangles, radiance)?);
        Ok(())
    }

    /// The scene's area lights, in the order they were added.
    pub fn area_lights(&self) -> &[AreaLight] {
        &self.lights
    }

    /// The light of object `object`, if it emits.
    pub fn emitter(&self, object: u32) -> Option<&AreaLight> {
        self.lights.iter().find(|l| l.object == object)
    }

    /// Radiance leaving the surface at `hit` towards `towards_viewer` if it is an emitter.
    pub fn emitted(&self, hit: &SurfaceHit, towards_viewer: Vec3) -> Vec3 {
        match self.emitter(hit.obj) {
            Some(light) => {
                let first = self.mesh.objects[hit.obj as usize].first_triangle;
                light.emitted((hit.prim - first) as usize, towards_viewer)
            }
            None => Vec3::ZERO,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_quad() -> Scene {
        let mut s = Scene::new();
        let v = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        s.add_indexed(&v, &[[0, 1, 2], [0, 2, 3]], Material::DEFAULT, None)
            .unwrap();
        s
    }

    #[test]
    fn batch_validation_names_the_argument() {
        let s = unit_quad();
        let o = [[0.5, 0.5, 1.0]];
        let cases: [(RayBatch, &str); 5] = [
            (RayBatch::new(&o, &[[0.0, 0.0, 0.0]]), "directions"),
            (
                RayBatch::new(&[[f32::NAN, 0.0, 0.0]], &[[0.0, 0.0, -1.0]]),
                "origins",
            ),
            (RayBatch::new(&o, &[]), "directions"),
            (
                RayBatch {
                    tmax: TMax::Scalar(-1.0),
                    ..RayBatch::new(&o, &[[0.0, 0.0, -1.0]])
                },
                "tmax",
            ),
            (
                RayBatch {
                    tmax: TMax::PerRay(&[]),
                    ..RayBatch::new(&o, &[[0.0, 0.0, -1.0]])
                },
                "tmax",
            ),
        ];
        for (batch, name) in cases {
            let e = s.occluded(&batch, None).unwrap_err().to_string();
            assert!(e.starts_with(name), "{e}");
        }
        // Large batches, whose chunks validate their own rays while others trace theirs:
        // the first bad row of the first bad argument is named, on any thread count, and
        // the chunks traced before the error count nothing.
        let n = 5 * CHUNK + 17;
        let (mut o, mut d) = (vec![[0.5, 0.5, 1.0]; n], vec![[0.0, 0.0, -1.0]; n]);
        let mut tmax = vec![1.0; n];
        d[4 * CHUNK + 3] = [0.0; 3];
        d[CHUNK + 1] = [f32::INFINITY, 0.0, 1.0];
        tmax[7] = -2.0;
        let message = |o: &[[f32; 3]], d: &[[f32; 3]], threads| {
            let batch = RayBatch {
                tmax: TMax::PerRay(&tmax),
                ..RayBatch::new(o, d)
            };
            s.occluded(&batch, threads).unwrap_err().to_string()
        };
        for threads in [Some(1), Some(2)] {
            let e = message(&o, &d, threads);
            assert!(
                e.starts_with(&format!("directions: row {}", CHUNK + 1)),
                "{e}"
            );
        }
        o[3 * CHUNK + 5] = [0.0, f32::NAN, 0.0];
        o[n - 1] = [f32::NEG_INFINITY, 0.0, 0.0];
        for threads in [Some(1), Some(2)] {
            let e = message(&o, &d, threads);
            assert!(
                e.starts_with(&format!("origins: row {}", 3 * CHUNK + 5)),
                "{e}"
            );
        }
        let (o, d) = (vec![[0.5, 0.5, 1.0]; n], vec![[0.0, 0.0, -1.0]; n]);
        assert!(message(&o, &d, None).starts_with("tmax: value 7"));
        assert_eq!(
            s.counters(),
            TraversalCounters::default(),
            "failed calls count nothing"
        );
        assert_eq!(
            s.occluded(&RayBatch::new(&o, &d), Some(2)).unwrap(),
            vec![true; n]
        );
        assert_eq!(s.counters().rays, n as u64);
    }

    #[test]
    fn batch_answers_and_counters() {
        let s = unit_quad();
        let o = [[0.5, 0.25, 1.0], [2.0, 2.0, 1.0], [0.25, 0.5, -1.0]];
        let d = [[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]];
        let occ = s.occluded(&RayBatch::new(&o, &d), Some(2)).unwrap();
        assert_eq!(occ, vec![true, false, true]);
        let hits = s.intersect(&RayBatch::new(&o, &d), Some(1)).unwrap();
        assert_eq!(hits.prim[1], -1);
        assert!(hits.t[1].is_infinite() && hits.position[1][0].is_nan());
        assert_eq!(hits.t[0], 1.0);
        assert_eq!(hits.prim[0], 0);
        assert_eq!(hits.prim[2], 1);
        assert_eq!(hits.normal[0], [0.0, 0.0, 1.0]);
        assert_eq!(hits.position[2], [0.25, 0.5, 0.0]);
        assert_eq!(s.counters().rays, 6);
        s.reset_counters();
        s.set_counting(false);
        s.occluded(&RayBatch::new(&o, &d), None).unwrap();
        assert_eq!(s.counters(), TraversalCounters::default());
    }

    /// Large batches of scattered rays in a tree larger than L2 are traced in the Morton
    /// order of their origins, and record bundles in the Morton order of their points;
    /// they answer as each ray traced alone, with counters that count the batch's rays,
    /// the same on one and two threads. Batches that take that path and batches that do
    /// not (too few rays, bundles already in order) are both covered.
    #[test]
    fn reordered_batches_answer_as_single_rays() {
        let scene = crate::scenes::load("garden", 0.25, 3).unwrap().scene;
        assert!(
            scene.bvh().outgrows_l2(),
            "the test needs a tree larger than L2"
        );
        let (o, d) = crate::testing::ground_hemisphere_rays(&scene, SPATIAL_ORDER_MIN + 77, 5);
        let rays = RayBatch::new(&o, &d);
        assert!(
            matches!(scene.spatial_order(&rays), TraceOrder::Rays(_)),
            "this batch must be reordered"
        );
        let (bo, bd) = crate::testing::record_bundle_rays(&scene, 70, 32, 5);
        let bundles = RayBatch::new(&bo, &bd);
        let TraceOrder::Runs(order) = scene.spatial_order(&bundles) else {
            panic!("scattered bundles are reordered")
        };
        // Each bundle is traced whole, from its first ray to its last.
        assert_eq!(order.len(), 70);
        assert!(order.iter().all(|r| r.start % 1024 == 0 && r.len() == 1024));
        let sorted: Vec<u32> = order.iter().map(|r| r.start / 1024).collect();
        let (so, sd): (Vec<_>, Vec<_>) = sorted
            .iter()
            .flat_map(|&k| (k as usize * 1024..(k as usize + 1) * 1024).map(|i| (bo[i], bd[i])))
            .unzip();
        assert!(
            scene.spatial_order(&RayBatch::new(&so, &sd)) == TraceOrder::Given,
            "bundles in order stay as given"
        );
        let few = RayBatch::new(&o[..1000], &d[..1000]);
        assert_eq!(scene.spatial_order(&few), TraceOrder::Given);
        let cycled_tmax =
            |n: usize| -> Vec<f32> { (0..n).map(|i| [f32::INFINITY, 0.05, 0.3][i % 3]).collect() };
        let tmax = cycled_tmax(o.len());
        let limited = RayBatch {
            tmax: TMax::PerRay(&tmax),
            ..rays
        };
        let bundle_tmax = cycled_tmax(bo.len());
        let limited_bundles = RayBatch {
            tmax: TMax::PerRay(&bundle_tmax),
            ..bundles
        };
        for batch in [rays, limited, bundles, limited_bundles] {
            let alone: Vec<bool> = (0..batch.len())
                .map(|i| {
                    let mut c = TraversalCounters::default();
                    scene.occluded1(
                        Vec3::from(batch.origins[i]),
                        Vec3::from(batch.directions[i]),
                        batch.tmax_of(i),
                        &mut c,
                    )
                })
                .collect();
            scene.set_counting(true);
            scene.reset_counters();
            let one = scene.occluded(&batch, Some(1)).unwrap();
            let counted_one = scene.counters();
            scene.reset_counters();
            let two = scene.occluded(&batch, Some(2)).unwrap();
            assert_eq!(one, alone);
            assert_eq!(two, alone);
            assert_eq!(counted_one, scene.counters());
            assert_eq!(counted_one.rays, batch.len() as u64);
            assert!(alone.iter().any(|&a| a) && alone.iter().any(|&a| !a));
        }
        scene.set_counting(false);
    }

    /// Runs of rays from one origin stay whole and go in the order of their origins' keys
    /// (ties in the given order); runs in that order already, or a single run, stay put.
    #[test]
    fn bundle_order_keeps_runs_whole() {
        let o = |x: f32| [x, 0.0, 0.0];
        // Runs: 3 at x=2, 1 at x=0, 2 at x=1, 2 at x=0 (a second run from that point).
        let origins = [o(2.), o(2.), o(2.), o(0.), o(1.), o(1.), o(0.), o(0.)];
        let key = |p: &[f32; 3]| p[0] as u64;
        assert_eq!(
            bundle_order(&origins, key),
            Some(vec![3..4, 6..8, 4..6, 0..3])
        );
        let in_order = [o(0.), o(0.), o(1.), o(2.), o(2.)];
        assert_eq!(bundle_order(&in_order, key), None);
        assert_eq!(bundle_order(&[o(5.); 4], key), None);
        assert_eq!(bundle_order(&[], key), None);
        // -0.0 and 0.0 start different runs (origins are compared bit for bit).
        let signed = [o(1.), [-0.0, 0.0, 0.0], o(0.)];
        assert_eq!(
            bundle_order(&signed, |p| p[0].abs() as u64),
            Some(vec![1..2, 2..3, 0..1])
        );
    }

    /// Bundles from one origin in pattern order (where the occluder hint is used) answer as
    /// the same rays traced one at a time without hints, on a closed box and open ground.
    #[test]
    fn hinted_bundles_answer_as_single_rays() {
        use crate::sampling::pattern::default_pattern;
        use crate::testing::surface_points;
        let pattern = default_pattern(5).unwrap();
        for (name, ground) in [
            ("cornell", "floor"),
            ("garden", "ground"),
            ("garage", "floor"),
        ] {
            let s = crate::scenes::load(name, 1.0, 0).unwrap().scene;
            let (mut origins, mut dirs) = (Vec::new(), Vec::new());
            for (p, n) in surface_points(&s, Some(ground), 64, 3) {
                let o = s.offset_point(p, n).to_array();
                for d in pattern.iter().filter(|d| n.dot(**d) > -0.2) {
                    origins.push(o);
                    dirs.push(d.to_array());
                }
            }
            let bundled = s
                .occluded(&RayBatch::new(&origins, &dirs), Some(2))
                .unwrap();
            let mut c = TraversalCounters::default();
            let single: Vec<bool> = origins
                .iter()
                .zip(&dirs)
                .map(|(o, d)| s.occluded1(Vec3::from(*o), Vec3::from(*d), f32::INFINITY, &mut c))
                .collect();
            assert_eq!(bundled, single, "{name}");
            let occluded = single.iter().filter(|&&b| b).count();
            if name == "cornell" {
                assert_eq!(occluded, single.len(), "the closed box blocks every ray");
            } else {
                assert!(
                    occluded > 0 && occluded < single.len(),
                    "{name}: a mix of answers"
                );
            }
        }
    }

    /// Runs of 1 to 23 rays from one origin, in narrow cones (traced as packets) and in
    /// scattered directions (one by one), with per-ray `tmax`, across chunk boundaries:
    /// the answers are single rays' on 1 and 2 threads, and the counters count every ray.
    #[test]
    fn runs_of_any_length_answer_as_single_rays() {
        use crate::sampling::rng::{hash4, to_unit_f32};
        use crate::testing::surface_points;
        let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 17));
        let s = crate::scenes::load("garage", 1.0, 0).unwrap().scene;
        let (mut origins, mut dirs, mut tmax) = (Vec::new(), Vec::new(), Vec::new());
        for (k, (p, n)) in surface_points(&s, None, 400, 5).into_iter().enumerate() {
            let k = k as u64;
            let o = s.offset_point(p, n).to_array();
            let axis = (n + Vec3::new(unit(1, k), unit(2, k), unit(3, k)) - 0.5).normalize();
            let spread = [0.1, 0.4, 4.0][k as usize % 3];
            for l in 0..1 + (7 * k) % 23 {
                let r = 64 * k + l;
                let jitter = Vec3::new(unit(4, r), unit(5, r), unit(6, r)) - 0.5;
                origins.push(o);
                dirs.push((axis + jitter * spread).to_array());
                tmax.push([f32::INFINITY, 2.0, 0.5][(r % 3) as usize]);
            }
        }
        assert!(origins.len() > 2 * CHUNK);
        let rays = RayBatch {
            origins: &origins,
            directions: &dirs,
            tmax: TMax::PerRay(&tmax),
        };
        s.set_counting(true);
        s.reset_counters();
        let one = s.occluded(&rays, Some(1)).unwrap();
        assert_eq!(s.counters().rays, origins.len() as u64);
        s.set_counting(false);
        assert_eq!(s.occluded(&rays, Some(2)).unwrap(), one);
        let mut c = TraversalCounters::default();
        let single: Vec<bool> = (0..origins.len())
            .map(|i| s.occluded1(Vec3::from(origins[i]), Vec3::from(dirs[i]), tmax[i], &mut c))
            .collect();
        assert_eq!(one, single);
        let occluded = single.iter().filter(|&&b| b).count();
        assert!(
            occluded > 500 && occluded < single.len() - 500,
            "{occluded}"
        );
        // Every instruction set's chunk loop: the same answers and counts as the portable.
        let bvh = s.bvh();
        let chunk = |f: &dyn Fn(&mut [bool], &mut TraversalCounters)| {
            let (mut out, mut c) = (vec![false; origins.len()], TraversalCounters::default());
            f(&mut out, &mut c);
            (out, c)
        };
        let portable = chunk(&|out, c| {
            let trace =
                |o, d, t, hint: &mut _, c: &mut _| bvh.hinted_portable::<true>(o, d, t, hint, c);
            occluded_chunk_with::<true>(bvh, &rays, 0, out, c, trace)
        });
        assert_eq!(portable.0, one);
        #[cfg(target_arch = "x86_64")]
        {
            use crate::simd::SimdLevel;
            if crate::simd::level() >= SimdLevel::Avx2 {
                // SAFETY: the CPU has AVX2.
                let avx2 =
                    chunk(&|out, c| unsafe { occluded_chunk_avx2::<true>(bvh, &rays, 0, out, c) });
                assert_eq!(avx2, portable);
            }
            if crate::simd::level() >= SimdLevel::Avx512 {
                // SAFETY: the CPU has AVX-512 F and VL.
                let avx512 = chunk(&|out, c| unsafe {
                    occluded_chunk_avx512::<true>(bvh, &rays, 0, out, c)
                });
                assert_eq!(avx512, portable);
            }
        }
    }

    /// `n` rays from points uniform in `b` (grown by `margin`) in uniform directions, some
    /// with a finite `tmax`.
    fn random_rays(b: Bounds, margin: f32, n: usize, seed: u64) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
        use crate::sampling::rng::SampleRng;
        use crate::scenes::shapes::sphere_dir;
        let (lo, hi) = (b.min - margin, b.max + margin);
        (0..n as u64)
            .map(|i| {
                let r = SampleRng::new(seed, i, 0);
                let [a, c] = r.get2(0);
                let p = lo + (hi - lo) * Vec3::new(a, c, r.get(2));
                let [u, v] = r.get2(3);
                (p.to_array(), sphere_dir(u, v).to_array())
            })
            .unzip()
    }

    /// Occluded answers (unbounded and with tmax 1) and closest hits of `s` on the rays.
    fn answers(s: &Scene, o: &[[f32; 3]], d: &[[f32; 3]]) -> (Vec<bool>, Vec<bool>, Hits) {
        let rays = RayBatch::new(o, d);
        let short = RayBatch {
            tmax: TMax::Scalar(1.0),
            ..rays
        };
        (
            s.occluded(&rays, None).unwrap(),
            s.occluded(&short, None).unwrap(),
            s.intersect(&rays, None).unwrap(),
        )
    }

    /// Panics with the number of differing rays and the first, if the answers differ.
    /// Shadow answers must agree exactly, and so must closest hits, except that trees of
    /// other topologies may return different triangles where two lie at the same `t` up to
    /// rounding (a box's bottom face on the ground, a shared edge): the traversal finds the
    /// closest hit up to a few ulps, and which of such a pair it returns depends on the
    /// order it visits them.
    fn assert_same_answers(s: &Scene, t: &Scene, o: &[[f32; 3]], d: &[[f32; 3]], what: &str) {
        let (a, b) = (answers(s, o, d), answers(t, o, d));
        let differ: Vec<usize> = (0..o.len())
            .filter(|&i| {
                let (ta, tb) = (a.2.t[i], b.2.t[i]);
                let tie = (ta - tb).abs() <= 1e-6 * ta.max(tb);
                a.0[i] != b.0[i]
                    || a.1[i] != b.1[i]
                    || ((ta != tb || a.2.prim[i] != b.2.prim[i]) && !tie)
            })
            .collect();
        if let Some(&i) = differ.first() {
            panic!(
                "{what}: {} of {} rays differ; first {i}: ray {:?} {:?}: occluded {} {} / {} {}, hit t {} {}, prim {} {}",
                differ.len(),
                o.len(),
                o[i],
                d[i],
                a.0[i],
                b.0[i],
                a.1[i],
                b.1[i],
                a.2.t[i],
                b.2.t[i],
                a.2.prim[i],
                b.2.prim[i]
            );
        }
    }

    fn sphere_of_dynamics() -> (Scene, u32) {
        let s = crate::scenes::load("dynamics", 0.5, 0).unwrap().scene;
        let id = s.mesh().objects.iter().position(|o| o.name == "sphere");
        (s, id.unwrap() as u32)
    }

    fn some_motion(k: f32) -> Affine3A {
        Affine3A::from_rotation_translation(
            glam::Quat::from_euler(glam::EulerRot::XYZ, 0.3 * k, 1.1 * k, -0.2 * k),
            Vec3::new(-0.7 * k, 0.05 * k, 0.9 * k),
        )
    }

    #[test]
    fn moving_an_object_answers_as_moving_its_vertices_and_rebuilding() {
        let (mut s, sphere) = sphere_of_dynamics();
        s.bvh();
        let range = {
            let o = &s.mesh().objects[sphere as usize];
            o.first_triangle as usize..(o.first_triangle + o.num_triangles) as usize
        };
        let rest = s.mesh().clone();
        for (k, update) in [
            (1.0, BvhUpdate::Refit),
            (2.0, BvhUpdate::Rebuild),
            (-1.5, BvhUpdate::Refit),
        ] {
            let t = some_motion(k);
            s.set_object_transform_with(sphere, t, update).unwrap();
            assert_eq!(s.object_transform(sphere).unwrap(), t);
            let mut by_hand = rest.clone();
            for tri in &mut by_hand.triangles[range.clone()] {
                *tri = tri.map(|v| t.transform_point3(v));
            }
            assert_eq!(s.mesh().triangles, by_hand.triangles);
            let by_hand = Scene::from_mesh(by_hand);
            assert_eq!(s.bounds(), by_hand.bounds());
            let (o, d) = random_rays(
                s.object_bounds(sphere).unwrap(),
                1.0,
                4000,
                k.to_bits() as u64,
            );
            assert_same_answers(&s, &by_hand, &o, &d, &format!("{update:?} {k}"));
            let a = answers(&s, &o, &d);
            let hits = a.2.obj.iter().filter(|&&o| o == sphere as i32).count();
            assert!(
                hits > 200 && a.0.iter().any(|x| !x),
                "rays see the sphere: {hits}"
            );
        }
        // Back to the identity: the rest pose, bit for bit, after any number of poses.
        s.set_object_transform(sphere, Affine3A::IDENTITY).unwrap();
        let bits = |m: &Mesh| -> Vec<u32> {
            m.triangles
                .iter()
                .flatten()
                .flat_map(|v| v.to_array().map(f32::to_bits))
                .collect()
        };
        assert_eq!(bits(s.mesh()), bits(&rest));
    }

    #[test]
    fn refit_traces_as_rebuild_and_keeps_the_topology() {
        let (mut refit, sphere) = sphere_of_dynamics();
        refit.bvh();
        assert!(!refit.is_posed(sphere));
        refit
            .set_object_transform(sphere, Affine3A::IDENTITY)
            .unwrap();
        assert!(
            refit.is_posed(sphere) && !refit.is_built(),
            "the first move drops the tree"
        );
        let nodes_before = refit.bvh().num_nodes();
        let mut rebuilt = refit.clone();
        for k in [0.25f32, 0.5, 1.0, 3.0] {
            refit.set_object_transform(sphere, some_motion(k)).unwrap();
            rebuilt
                .set_object_transform_with(sphere, some_motion(k), BvhUpdate::Rebuild)
                .unwrap();
            assert!(refit.is_built() && !rebuilt.is_built());
            assert_eq!(refit.bvh().num_nodes(), nodes_before, "topology kept");
            let (o, d) = random_rays(refit.bounds(), 0.0, 3000, 7);
            let (o2, d2) = random_rays(refit.object_bounds(sphere).unwrap(), 0.5, 3000, 8);
            for (o, d) in [(o, d), (o2, d2)] {
                assert_same_answers(&refit, &rebuilt, &o, &d, &format!("k = {k}"));
            }
        }
    }

    #[test]
    fn bad_motion_arguments_leave_the_scene_unchanged() {
        let (mut s, sphere) = sphere_of_dynamics();
        s.set_object_transform(sphere, some_motion(0.5)).unwrap();
        s.bvh();
        let (tris, bounds) = (s.mesh().triangles.clone(), s.bounds());
        let cases = [
            (s.num_objects() as u32, Affine3A::IDENTITY, "object"),
            (u32::MAX, Affine3A::IDENTITY, "object"),
            (
                sphere,
                Affine3A::from_translation(Vec3::new(f32::NAN, 0.0, 0.0)),
                "transform",
            ),
            (
                sphere,
                Affine3A::from_scale(Vec3::splat(f32::INFINITY)),
                "transform",
            ),
            (sphere, Affine3A::from_scale(Vec3::splat(3e38)), "transform"),
        ];
        for (object, t, name) in cases {
            for update in [BvhUpdate::Refit, BvhUpdate::Rebuild] {
                let e = s
                    .set_object_transform_with(object, t, update)
                    .unwrap_err()
                    .to_string();
                assert!(e.starts_with(name), "{e}");
                assert_eq!(s.mesh().triangles, tris);
                assert_eq!(s.bounds(), bounds);
                assert!(s.is_built());
                assert_eq!(s.object_transform(sphere).unwrap(), some_motion(0.5));
            }
        }
        assert!(s
            .object_transform(99)
            .unwrap_err()
            .to_string()
            .starts_with("object"));
        assert!(s
            .object_bounds(99)
            .unwrap_err()
            .to_string()
            .starts_with("object"));
    }

    #[test]
    fn flattening_an_object_falls_back_to_a_rebuild() {
        // Scale 0 along y makes the pillar's side triangles degenerate (its top and bottom
        // stay non-degenerate): the refit must notice and rebuild, and the answers match a
        // scene built from the flattened triangles.
        let (mut s, _) = sphere_of_dynamics();
        let pillar = s
            .mesh()
            .objects
            .iter()
            .position(|o| o.name == "pillar")
            .unwrap() as u32;
        s.bvh();
        let flat = Affine3A::from_scale(Vec3::new(1.0, 0.0, 1.0));
        s.set_object_transform(pillar, flat).unwrap();
        let b = s.object_bounds(pillar).unwrap();
        assert_eq!((b.min.y, b.max.y), (0.0, 0.0));
        let by_hand = Scene::from_mesh(s.mesh().clone());
        let (o, d) = random_rays(b, 1.0, 3000, 3);
        assert_same_answers(&s, &by_hand, &o, &d, "flattened");
        // And back.
        s.set_object_transform(pillar, Affine3A::IDENTITY).unwrap();
        let b = s.object_bounds(pillar).unwrap();
        assert_eq!((b.min.y, b.max.y), (0.0, 2.5));
    }

    #[test]
    fn moving_an_emitter_moves_its_light_and_an_empty_object_is_fine() {
        let mut s = unit_quad();
        let quad = [
            [0.0, 0.0, 2.0],
            [1.0, 0.0, 2.0],
            [1.0, 1.0, 2.0],
            [0.0, 1.0, 2.0],
        ];
        let light = s.add_area_light(&quad, [1.0, 2.0, 3.0], None).unwrap();
        let empty = s.add_indexed(&[], &[], Material::DEFAULT, None).unwrap();
        s.set_object_transform(empty, some_motion(1.0)).unwrap();
        let t = Affine3A::from_translation(Vec3::new(0.0, 0.0, 3.0));
        s.set_object_transform(light, t).unwrap();
        let l = s.emitter(light).unwrap();
        assert_eq!(l.radiance(), Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(s.object_bounds(light).unwrap().min.z, 5.0);
        assert_eq!(s.bounds().max.z, 5.0);
        // Scale 0 leaves the light without area: an error, nothing changes.
        let e = s
            .set_object_transform(light, Affine3A::from_scale(Vec3::ZERO))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("transform"), "{e}");
        assert_eq!(s.object_bounds(light).unwrap().min.z, 5.0);
        // Bounds stay those of all vertices with several moved objects and later additions.
        let far = [[0.0, 0.0, -7.0], [1.0, 0.0, -7.0], [0.0, 1.0, -7.0]];
        let added = s
            .add_indexed(&far, &[[0, 1, 2]], Material::DEFAULT, None)
            .unwrap();
        assert_eq!(s.bounds(), s.mesh().bounds());
        for (object, z) in [(0, -9.0), (added, 4.0), (light, -1.0), (added, 0.0)] {
            let t = Affine3A::from_translation(Vec3::new(0.0, 0.0, z));
            s.set_object_transform(object, t).unwrap();
            assert_eq!(s.bounds(), s.mesh().bounds(), "object {object} to {z}");
        }
        assert_eq!(s.bounds().min.z, -9.0);
    }
}
