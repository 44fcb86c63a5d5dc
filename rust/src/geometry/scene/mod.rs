//! A scene: a [`Mesh`], the BVH over it (built on first query), and traversal counters.
//! All batched queries validate every ray first and fail without side effects.
//!
//! Objects can be moved rigidly (any finite affine map) with
//! [`Scene::set_object_transform`]: the scene keeps each moved object's rest-pose
//! triangles and maps those, so a sequence of poses never accumulates rounding, and it
//! refits (or drops) the BVH.
//!
//! Files: `batch.rs` (ray batches and their validation), `schedule.rs` (how batches are
//! split into work items and ordered for coherence), `motion.rs` (rigid motion of objects),
//! `emitters.rs` (area lights).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::OnceLock;

use glam::{Vec3, Vec3A};

use super::bvh::{BuildQuality, Bvh, Hit, TraversalCounters, PACKET};
use super::mesh::{Bounds, Mesh};
use crate::bsdf::Material;
use crate::error::Result;
use crate::lights::area::AreaLight;
use crate::math::triangle_cross;

mod batch;
mod emitters;
mod motion;
mod schedule;

#[cfg(test)]
mod tests;

pub use batch::{BadArgument, Hits, RayBatch, TMax, MAX_DIRECTION_LENGTH, MIN_DIRECTION_LENGTH};
use motion::Posed;
pub use schedule::MIN_PACKET;

/// Bytes a BVH build may take at its peak per triangle of the mesh, with 1.5x margin: the
/// peak resident growth of building 1M random triangles measured at most 215 bytes a
/// triangle ("auto" and "sah" alike; "auto" builds one tree above 262,144 triangles).
pub const BVH_BUILD_BYTES_PER_TRIANGLE: usize = 320;

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
            let mut h = Digest::default();
            h.word(self.mesh.objects.len() as u64);
            for i in 0..self.mesh.objects.len() {
                let triangles = match self.posed.get(&(i as u32)) {
                    Some(p) => &p.rest[..],
                    None => self.triangles_of(i),
                };
                h.word(triangles.len() as u64);
                for v in triangles.iter().flatten() {
                    h.word(v.x.to_bits() as u64 | (v.y.to_bits() as u64) << 32);
                    h.word(v.z.to_bits() as u64);
                }
            }
            h.finish()
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

    /// Fails with [`crate::Error::OutOfMemory`] (naming `scene`) when the BVH is not built
    /// yet and a build's peak ([`BVH_BUILD_BYTES_PER_TRIANGLE`] a triangle) cannot be
    /// allocated now. The builders allocate internally (one of them in another crate), so
    /// their worst case is probed before they start: a scene too large for the memory
    /// left is an error, not an abort part-way through the build.
    pub fn check_bvh_memory(&self) -> Result<()> {
        if self.is_built() {
            return Ok(());
        }
        crate::alloc::check_memory(
            self.mesh
                .triangles
                .len()
                .saturating_mul(BVH_BUILD_BYTES_PER_TRIANGLE),
            "scene",
        )
    }

    /// Builds the BVH now with the given preset (on the current rayon pool).
    pub fn build(&mut self, quality: BuildQuality) -> &Bvh {
        self.quality = quality;
        self.bvh = OnceLock::new();
        self.bvh()
    }

    /// A BVH of the scene as it is now with preset `quality` (on the current rayon pool),
    /// built aside: the scene is not changed until [`Self::install_bvh`]. For callers that
    /// must be able to walk away from a build (the tree builders cannot be stopped
    /// part-way).
    pub fn build_aside(&self, quality: BuildQuality) -> Bvh {
        Bvh::build_grouped(&self.mesh, quality, &self.posed_ranges())
    }

    /// Makes `bvh`, built by [`Self::build_aside`] with `quality` from a scene of the same
    /// pose fingerprint ([`Self::pose_fingerprint`]) as `built_for`, this scene's tree.
    /// Returns false, changing nothing, when the scene changed since.
    pub fn install_bvh(&mut self, quality: BuildQuality, built_for: u64, bvh: Bvh) -> bool {
        if self.pose_fingerprint() != built_for {
            return false;
        }
        self.quality = quality;
        self.bvh = OnceLock::from(bvh);
        true
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
            .map(|&o| self.mesh.objects[o as usize].triangle_range())
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

    /// The end of a shadow segment `distance` long toward `target`, a point on a surface
    /// (a light, an emitter's plane): short of it by twice [`Self::ray_epsilon`] there, so
    /// that the target's own triangle is not hit. May be `<= 0` when the target is that
    /// close.
    pub fn segment_end(&self, distance: f32, target: Vec3) -> f32 {
        distance - 2.0 * self.ray_epsilon(target)
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

    /// [`Self::occluded1`] counting only the triangles of objects `keep` accepts (by object
    /// id): BLD's visibility splitting (eq. 27) tests one object apart from the rest. The
    /// filter is asked only about triangles on the segment; [`Self::occluded1`] itself is
    /// untouched by it.
    #[inline]
    pub fn occluded1_objects(
        &self,
        origin: Vec3,
        direction: Vec3,
        tmax: f32,
        keep: impl Fn(u32) -> bool,
        c: &mut TraversalCounters,
    ) -> bool {
        let bvh = self.bvh();
        let ids = &self.mesh.object_ids;
        let keep_triangle = |t: u32| keep(ids[t as usize]);
        if self.counting_enabled() {
            bvh.occluded_filtered::<true, _>(
                origin.into(),
                direction.into(),
                tmax,
                &keep_triangle,
                c,
            )
        } else {
            bvh.occluded_filtered::<false, _>(
                origin.into(),
                direction.into(),
                tmax,
                &keep_triangle,
                c,
            )
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
        Some(self.surface_hit(hit))
    }

    /// Closest hits of up to [`PACKET`] rays from one origin, traced together
    /// ([`Bvh::intersect_packet`]: each ray's distance is [`Self::intersect1`]'s); counts
    /// them if counting is on. Directions must be non-zero.
    pub fn intersect_packet(
        &self,
        origin: Vec3,
        directions: &[Vec3A],
        tmax: &[f32],
        c: &mut TraversalCounters,
    ) -> [Option<SurfaceHit>; PACKET] {
        let bvh = self.bvh();
        let hits = if self.counting_enabled() {
            bvh.intersect_packet::<true>(origin.into(), directions, tmax, c)
        } else {
            bvh.intersect_packet::<false>(origin.into(), directions, tmax, c)
        };
        hits.map(|h| h.map(|h| self.surface_hit(h)))
    }

    /// The surface at a BVH hit.
    #[inline]
    fn surface_hit(&self, hit: Hit) -> SurfaceHit {
        let tri = &self.mesh.triangles[hit.triangle as usize];
        let w = 1.0 - hit.u - hit.v;
        SurfaceHit {
            t: hit.t,
            prim: hit.triangle,
            obj: self.mesh.object_ids[hit.triangle as usize],
            u: hit.u,
            v: hit.v,
            position: tri[0] * w + tri[1] * hit.u + tri[2] * hit.v,
            normal: triangle_cross(tri).normalize(),
        }
    }

    /// Closest hits.
    pub fn intersect(&self, rays: &RayBatch, threads: Option<usize>) -> Result<Hits> {
        rays.validate()?;
        let found = self.closest_hits(rays, threads)?;
        // Hit points and normals read each hit's triangle, a wait on memory per hit in a
        // large mesh: computed on the workers too, in the rays' order.
        let surface: Vec<Option<SurfaceHit>> = crate::parallel::with_threads(threads, || {
            use rayon::prelude::*;
            found
                .par_iter()
                .with_min_len(schedule::CHUNK)
                .map(|h| h.map(|h| self.surface_hit(h)))
                .collect()
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
        for h in surface {
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

/// FxHash-style mixing of 64-bit words, then the splitmix64 finaliser: not
/// cryptographic, but any edit of a word changes the digest.
#[derive(Default)]
pub(crate) struct Digest(u64);

impl Digest {
    pub(crate) fn word(&mut self, w: u64) {
        self.0 = (self.0.rotate_left(5) ^ w).wrapping_mul(0x517c_c1b7_2722_0a95);
    }

    pub(crate) fn finish(&self) -> u64 {
        let h = self.0;
        let mut z = h ^ (h >> 30);
        z = z.wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
}
