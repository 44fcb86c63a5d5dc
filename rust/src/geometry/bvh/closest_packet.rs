//! Packets of up to [`PACKET`] closest-hit rays from one origin: a pinhole camera's rays
//! through one pixel, which visit nearly the same nodes and leaves.

use glam::Vec3A;

use super::packet::PACKET;
#[cfg(target_arch = "x86_64")]
use super::packet::{LaneRays, Packet, VECTOR_TRIANGLE_LANES};
use super::{Bvh, Hit, TraversalCounters};
#[cfg(target_arch = "x86_64")]
use super::{FarthestFirst, STACK};
#[cfg(target_arch = "x86_64")]
use crate::geometry::bvh::bvh8::{decode, BoundedStack, Child, Stack, TraversalStack, EXIT_SCALE};
#[cfg(target_arch = "x86_64")]
use crate::geometry::bvh::watertight::lanes;
use crate::simd::{Kernel, Level};

/// A lane's closest triangle: its block slot and barycentrics `(u, v)`.
#[cfg(target_arch = "x86_64")]
type LaneHit = (u32, f32, f32);

impl Bvh {
    /// Closest hits of up to [`PACKET`] rays from one `origin` (`directions[l]`,
    /// `tmax[l]`), traced together under AVX-512 (one by one elsewhere): each node's
    /// children are tested against every lane at once by [`Self::occluded_packet`]'s box
    /// test, against each lane's closest hit so far, and visited nearest first (by the
    /// least entry distance over the lanes that hit them); each lane tests the triangles of
    /// the leaves its own box tests reach with [`Self::intersect`]'s watertight test.
    /// Every lane therefore finds the distance [`Self::intersect`] finds for its ray; where
    /// two triangles are hit at exactly that distance (a ray through a shared edge), the
    /// packet may report the other one. Counters count each ray, each node test once per
    /// ray taking part, and each ray's triangle tests.
    pub fn intersect_packet<const COUNT: bool>(
        &self,
        origin: Vec3A,
        directions: &[Vec3A],
        tmax: &[f32],
        counters: &mut TraversalCounters,
    ) -> [Option<Hit>; PACKET] {
        assert!(directions.len() <= PACKET && tmax.len() == directions.len());
        crate::simd::dispatch_avx512(ClosestPacket::<COUNT> {
            bvh: self,
            origin,
            directions,
            tmax,
            counters,
        })
    }

    /// The traversal of [`Self::intersect_packet`] under AVX-512: per lane, the distance
    /// (local frame) of its closest triangle so far, and the triangle's block slot and
    /// barycentrics when one was hit. Stack entries hold a child, the lanes that hit it
    /// and their least entry distance, so that an entry behind every one of its lanes'
    /// closest hits is dropped when popped.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl,popcnt")]
    fn closest_packet<const COUNT: bool, S: TraversalStack<((u32, u16), f32)>>(
        &self,
        packet: &Packet,
        rays: &mut LaneRays,
        counters: &mut TraversalCounters,
    ) -> ([f32; PACKET], [Option<LaneHit>; PACKET]) {
        use std::arch::x86_64::*;
        let (mut nodes, mut tests) = (0u64, 0u64);
        let mut best_t = lanes(packet.tmax);
        let mut best = [None; PACKET];
        // `best_t` in a register, and the box tests' exit (`best_t · EXIT_SCALE`).
        let mut best_v = packet.tmax;
        let mut exit = packet.exit;
        let mut stack = S::new();
        stack.push(((0, packet.all), 0.0));
        while let Some(((entry, lanes_in), t_enter)) = stack.pop() {
            // The lanes whose closest hit so far is not nearer than the entry.
            let live =
                _mm512_mask_cmp_ps_mask::<_CMP_GE_OQ>(lanes_in, best_v, _mm512_set1_ps(t_enter));
            if live == 0 {
                continue;
            }
            match decode(entry) {
                Child::Leaf { first, count } => {
                    let block = &self.blocks[first as usize];
                    if COUNT {
                        tests += count as u64 * live.count_ones() as u64;
                    }
                    if live.count_ones() >= VECTOR_TRIANGLE_LANES {
                        // Triangle after triangle against the lanes at once, each lane's
                        // closest hit so far as its bound: the lowest triangle wins ties.
                        for k in 0..count as usize {
                            let (hit, t, u, v) = packet.watertight.hits_at(block, k, best_v, live);
                            if hit == 0 {
                                continue;
                            }
                            best_v = _mm512_mask_blend_ps(hit, best_v, t);
                            let (t, u, v) = (lanes(t), lanes(u), lanes(v));
                            let mut rest = hit;
                            while rest != 0 {
                                let l = rest.trailing_zeros() as usize % PACKET;
                                rest &= rest - 1;
                                best_t[l] = t[l];
                                best[l] = Some((first * 4 + k as u32, u[l], v[l]));
                            }
                        }
                        exit = _mm512_mul_ps(best_v, _mm512_set1_ps(EXIT_SCALE));
                        continue;
                    }
                    let mut rest = live;
                    let mut closer = false;
                    while rest != 0 {
                        let l = rest.trailing_zeros() as usize % PACKET;
                        rest &= rest - 1;
                        let r = rays.get(&packet.watertight, l);
                        let (mut hit, t, u, v) = r.intersect4(block, best_t[l]);
                        let (t, u, v) = (t.to_array(), u.to_array(), v.to_array());
                        // Nearest triangle; the lowest wins ties, as in `closest_hit`.
                        while hit != 0 {
                            let k = hit.trailing_zeros() as usize % 4;
                            hit &= hit - 1;
                            if t[k] < best_t[l] {
                                best_t[l] = t[k];
                                best[l] = Some((first * 4 + k as u32, u[k], v[k]));
                                closer = true;
                            }
                        }
                    }
                    if closer {
                        // SAFETY: `best_t` holds PACKET = 16 f32s.
                        best_v = unsafe { _mm512_loadu_ps(best_t.as_ptr()) };
                        exit = _mm512_mul_ps(best_v, _mm512_set1_ps(EXIT_SCALE));
                    }
                }
                Child::Node(node) => {
                    let n = &self.tree.nodes[node as usize];
                    if COUNT {
                        nodes += live.count_ones() as u64;
                    }
                    let relative = packet.relative_planes(n);
                    let mut touched = packet.children_touched(&relative);
                    let mut hits = FarthestFirst::new((0u32, 0u16));
                    while touched != 0 {
                        let j = touched.trailing_zeros() as usize;
                        touched &= touched - 1;
                        let (hit, t_near) = packet.box_entries(&relative, j, live, exit);
                        if hit != 0 {
                            // The least entry over the lanes that hit it.
                            hits.insert((n.child(j), hit), _mm512_mask_reduce_min_ps(hit, t_near));
                        }
                    }
                    self.push_farthest_first(&mut stack, &hits, |(r, _)| r);
                }
            }
        }
        if COUNT {
            counters.nodes += nodes;
            counters.triangles += tests;
        }
        (best_t, best)
    }
}

/// [`Bvh::intersect_packet`] as a [`Kernel`]: the packet under AVX-512, else its rays one
/// by one ([`Bvh::intersect`], which dispatches by itself).
struct ClosestPacket<'a, const COUNT: bool> {
    bvh: &'a Bvh,
    origin: Vec3A,
    directions: &'a [Vec3A],
    tmax: &'a [f32],
    counters: &'a mut TraversalCounters,
}

impl<const COUNT: bool> Kernel for ClosestPacket<'_, COUNT> {
    type Output = [Option<Hit>; PACKET];

    #[inline(always)]
    fn run<L: Level>(self, _level: L) -> [Option<Hit>; PACKET] {
        let Self {
            bvh,
            origin,
            directions,
            tmax,
            counters,
        } = self;
        let mut out = [None; PACKET];
        #[cfg(target_arch = "x86_64")]
        if bvh.traces_packets::<L>(directions.len()) {
            if COUNT {
                counters.rays += directions.len() as u64;
            }
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here the AVX-512 level (F, VL and popcnt among it); 1 to PACKET
            // rays.
            unsafe {
                let packet = Packet::new(bvh, origin, directions, tmax);
                let rays = &mut LaneRays::new(origin, directions, tmax);
                let found = if bvh.stack_is_bounded() {
                    type Bounded = BoundedStack<((u32, u16), f32), STACK>;
                    bvh.closest_packet::<COUNT, Bounded>(&packet, rays, counters)
                } else {
                    type Spilling = Stack<((u32, u16), f32), STACK>;
                    bvh.closest_packet::<COUNT, Spilling>(&packet, rays, counters)
                };
                let (best_t, best) = found;
                for (l, f) in best.into_iter().enumerate().take(directions.len()) {
                    out[l] = f.map(|(slot, u, v)| {
                        let r = bvh.local_ray(origin, directions[l], tmax[l]);
                        Hit {
                            t: best_t[l] * r.t_to_param,
                            triangle: bvh.triangle_ids[slot as usize],
                            u,
                            v,
                        }
                    });
                }
            }
            return out;
        }
        for (l, (&d, &t)) in directions.iter().zip(tmax).enumerate() {
            out[l] = bvh.intersect::<COUNT>(origin, d, t, counters);
        }
        out
    }
}
