//! Early-exit shadow queries that ignore some triangles: a filter on mesh triangle ids
//! (BLD §4.3's visibility splitting tests the object at the shading point apart from the
//! rest, `002_f6f7ae5fac667f5c.txt` eq. 27). The walk is a copy of the unfiltered one
//! (`shadow.rs`) that masks a leaf's hit lanes by the filter, so queries without a filter
//! run the unchanged code and pay nothing for it.

use glam::Vec3A;

use super::{Bvh, LocalRay, TraversalCounters, STACK};
use crate::geometry::bvh::bvh8::{decode, BoxTest, Child, LevelBoxTest, Stack};
use crate::simd::{Kernel, Level};

impl Bvh {
    /// [`Bvh::occluded`] counting only triangles `keep` accepts (by mesh triangle id): true
    /// when a kept triangle lies on the segment `origin + t direction`, `t` in `[0, tmax)`.
    /// `keep` is asked only about triangles the segment hits, so a cheap filter costs little
    /// more than the unfiltered query.
    #[inline]
    pub fn occluded_filtered<const COUNT: bool, F: Fn(u32) -> bool>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        keep: &F,
        counters: &mut TraversalCounters,
    ) -> bool {
        crate::simd::dispatch(FilteredRay::<COUNT, F> {
            bvh: self,
            origin,
            direction,
            tmax,
            keep,
            counters,
        })
    }

    /// The walk of [`Self::occluded_filtered`] from the root.
    #[inline(always)]
    fn filtered_walk<const COUNT: bool, F: Fn(u32) -> bool>(
        &self,
        r: &LocalRay,
        keep: &F,
        counters: &mut TraversalCounters,
        box_test: impl BoxTest,
    ) -> bool {
        if COUNT {
            counters.rays += 1;
        }
        if self.blocks.is_empty() {
            return false;
        }
        let (mut nodes, mut tests) = (0u64, 0u64);
        let mut stack = Stack::<u32, STACK>::new();
        let mut entry = 0u32;
        let mut found = false;
        loop {
            match decode(entry) {
                Child::Leaf { first, count } => {
                    if COUNT {
                        tests += count as u64;
                    }
                    let block = &self.blocks[first as usize];
                    let mut lanes = r.watertight.intersect4(block, r.tmax).0;
                    while lanes != 0 {
                        let lane = lanes.trailing_zeros() as usize;
                        lanes &= lanes - 1;
                        if keep(self.triangle_ids[4 * first as usize + lane]) {
                            found = true;
                            break;
                        }
                    }
                    if found {
                        break;
                    }
                }
                Child::Node(node) => {
                    let n = &self.tree.nodes[node as usize];
                    if COUNT {
                        nodes += 1;
                    }
                    let mut mask = box_test.test(n, &r.boxes, r.tmax).1;
                    while mask != 0 {
                        let i = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        stack.push(n.child(i));
                    }
                }
            }
            match stack.pop() {
                Some(e) => entry = e,
                None => break,
            }
        }
        if COUNT {
            counters.nodes += nodes;
            counters.triangles += tests;
        }
        found
    }
}

/// [`Bvh::occluded_filtered`] as a [`Kernel`], compiled once per instruction set.
struct FilteredRay<'a, const COUNT: bool, F> {
    bvh: &'a Bvh,
    origin: Vec3A,
    direction: Vec3A,
    tmax: f32,
    keep: &'a F,
    counters: &'a mut TraversalCounters,
}

impl<const COUNT: bool, F: Fn(u32) -> bool> Kernel for FilteredRay<'_, COUNT, F> {
    type Output = bool;

    #[inline(always)]
    fn run<L: Level>(self, level: L) -> bool {
        let r = self.bvh.local_ray(self.origin, self.direction, self.tmax);
        self.bvh
            .filtered_walk::<COUNT, F>(&r, self.keep, self.counters, LevelBoxTest(level))
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use crate::geometry::{BuildQuality, Mesh, Scene, TraversalCounters};
    use crate::sampling::rng::SampleRng;

    /// The scene of `scene`'s objects that `keep` accepts, built.
    fn only(scene: &Scene, keep: impl Fn(u32) -> bool) -> Scene {
        let mesh = scene.mesh();
        let mut m = Mesh::new();
        for (i, o) in mesh.objects.iter().enumerate() {
            let tris: Vec<[Vec3; 3]> = if keep(i as u32) {
                mesh.triangles[o.triangle_range()].to_vec()
            } else {
                Vec::new()
            };
            m.add_triangles(tris, o.material, None).unwrap();
        }
        let mut s = Scene::from_mesh(m);
        s.build(BuildQuality::default());
        s
    }

    /// Keeping every object is the unfiltered query; keeping one object, or all but one,
    /// is the query against a scene of just those objects, ray for ray.
    #[test]
    fn a_filtered_query_is_the_query_of_the_kept_objects() {
        let setup = crate::scenes::load("cornell", 0.25, 0).unwrap();
        let scene = &setup.scene;
        let b = scene.bounds();
        let mut c = TraversalCounters::default();
        let n = scene.num_objects() as u32;
        for k in 0..n {
            let alone = only(scene, |o| o == k);
            let without = only(scene, |o| o != k);
            for i in 0..400u64 {
                let r = SampleRng::new(7, k as u64, i);
                let at = |d: u64| {
                    let u = Vec3::new(r.get(d), r.get(d + 1), r.get(d + 2));
                    b.min + (b.max - b.min) * u
                };
                let (o, t) = (at(0), at(3));
                let dir = (t - o).normalize();
                let tmax = if i % 3 == 0 {
                    f32::INFINITY
                } else {
                    (t - o).length()
                };
                let all = scene.occluded1(o, dir, tmax, &mut c);
                assert_eq!(scene.occluded1_objects(o, dir, tmax, |_| true, &mut c), all);
                assert!(!scene.occluded1_objects(o, dir, tmax, |_| false, &mut c));
                assert_eq!(
                    scene.occluded1_objects(o, dir, tmax, |obj| obj == k, &mut c),
                    alone.occluded1(o, dir, tmax, &mut c),
                    "object {k} ray {i}"
                );
                assert_eq!(
                    scene.occluded1_objects(o, dir, tmax, |obj| obj != k, &mut c),
                    without.occluded1(o, dir, tmax, &mut c),
                    "all but {k} ray {i}"
                );
            }
        }
    }
}
