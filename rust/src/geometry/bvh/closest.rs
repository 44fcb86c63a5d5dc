//! Closest-hit queries.

use glam::Vec3A;

use super::{Bvh, FarthestFirst, Hit, LocalRay, TraversalCounters, STACK};
use crate::geometry::bvh::bvh8::{
    decode, BoundedStack, BoxTest, Child, LevelBoxTest, Stack, TraversalStack,
};
use crate::geometry::bvh::watertight::TriangleHit;
use crate::simd::{Kernel, Level, SimdLevel};

impl Bvh {
    /// Closest hit on `origin + t direction` with `t` in `[0, tmax)`, if any.
    #[inline]
    pub fn intersect<const COUNT: bool>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        counters: &mut TraversalCounters,
    ) -> Option<Hit> {
        if COUNT {
            counters.rays += 1;
        }
        if self.blocks.is_empty() {
            return None;
        }
        crate::simd::dispatch(ClosestRay::<COUNT> {
            bvh: self,
            origin,
            direction,
            tmax,
            counters,
        })
    }

    /// [`Self::intersect`] on a non-empty tree (the ray not yet counted) with the box tests
    /// of instruction set `level`, for code compiled for it ([`Kernel`]); the vector forms
    /// take the fixed stack where the tree allows it.
    #[inline(always)]
    fn closest_hit_at<const COUNT: bool, L: Level>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        counters: &mut TraversalCounters,
        level: L,
    ) -> Option<Hit> {
        let r = self.local_ray(origin, direction, tmax);
        let box_test = LevelBoxTest(level);
        if L::LEVEL >= SimdLevel::Avx2 && self.stack_is_bounded() {
            self.closest_hit::<COUNT, BoundedStack<_, STACK>>(&r, counters, box_test)
        } else {
            self.closest_hit::<COUNT, Stack<_, STACK>>(&r, counters, box_test)
        }
    }

    /// The traversal of [`Self::intersect`], with `box_test` one of the forms of
    /// [`Node8::intersect`].
    #[inline(always)]
    pub(super) fn closest_hit<const COUNT: bool, S: TraversalStack<(u32, f32)>>(
        &self,
        r: &LocalRay,
        counters: &mut TraversalCounters,
        box_test: impl BoxTest,
    ) -> Option<Hit> {
        let (mut nodes, mut tests) = (0u64, 0u64);
        let mut best_t = r.tmax;
        let mut best: Option<(u32, TriangleHit)> = None;
        // Entries carry their entry distance so that boxes behind the closest hit found so
        // far are skipped when popped.
        let mut stack = S::new();
        stack.push((0, 0.0));
        while let Some((reference, t_enter)) = stack.pop() {
            if t_enter > best_t {
                continue;
            }
            match decode(reference) {
                Child::Leaf { first, count } => {
                    if COUNT {
                        tests += count as u64;
                    }
                    self.nearest_in_leaf(r, first, &mut best_t, &mut best);
                }
                Child::Node(c) => {
                    let n = &self.tree.nodes[c as usize];
                    if COUNT {
                        nodes += 1;
                    }
                    let (t_near, mut mask) = box_test.test(n, &r.boxes, best_t);
                    let mut hits = FarthestFirst::new(0u32);
                    while mask != 0 {
                        let i = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        hits.insert(n.child(i), t_near[i]);
                    }
                    self.push_farthest_first(&mut stack, &hits, |r| r);
                }
            }
        }
        if COUNT {
            counters.nodes += nodes;
            counters.triangles += tests;
        }
        self.closest_of(r, best)
    }

    /// Tests leaf block `first` against `r` for hits nearer than `best_t`, keeping the
    /// nearest (its slot and hit) in `best` and its distance in `best_t`.
    #[inline(always)]
    pub(super) fn nearest_in_leaf(
        &self,
        r: &LocalRay,
        first: u32,
        best_t: &mut f32,
        best: &mut Option<(u32, TriangleHit)>,
    ) {
        let (mut hit, t, u, v) = r
            .watertight
            .intersect4(&self.blocks[first as usize], *best_t);
        let (t, u, v) = (t.to_array(), u.to_array(), v.to_array());
        // Nearest lane; the lowest lane wins ties, so the answer is deterministic.
        while hit != 0 {
            let l = hit.trailing_zeros() as usize;
            hit &= hit - 1;
            if t[l] < *best_t {
                *best_t = t[l];
                *best = Some((
                    first * 4 + l as u32,
                    TriangleHit {
                        t: t[l],
                        u: u[l],
                        v: v[l],
                    },
                ));
            }
        }
    }

    /// The caller's hit for the nearest slot and hit a walk of `r` kept.
    #[inline(always)]
    pub(super) fn closest_of(&self, r: &LocalRay, best: Option<(u32, TriangleHit)>) -> Option<Hit> {
        best.map(|(slot, h)| Hit {
            t: h.t * r.t_to_param,
            triangle: self.triangle_ids[slot as usize],
            u: h.u,
            v: h.v,
        })
    }
}

/// [`Bvh::intersect`] on a non-empty tree, as a [`Kernel`] compiled once per instruction
/// set.
pub(super) struct ClosestRay<'a, const COUNT: bool> {
    pub(super) bvh: &'a Bvh,
    pub(super) origin: Vec3A,
    pub(super) direction: Vec3A,
    pub(super) tmax: f32,
    pub(super) counters: &'a mut TraversalCounters,
}

impl<const COUNT: bool> Kernel for ClosestRay<'_, COUNT> {
    type Output = Option<Hit>;

    #[inline(always)]
    fn run<L: Level>(self, level: L) -> Option<Hit> {
        let ClosestRay {
            bvh,
            origin,
            direction,
            tmax,
            counters,
        } = self;
        bvh.closest_hit_at::<COUNT, L>(origin, direction, tmax, counters, level)
    }
}
