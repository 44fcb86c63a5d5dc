//! Packets of up to [`PACKET`] shadow rays from one origin, traced together under
//! AVX-512 (one by one elsewhere), with the answers of single rays.

use glam::Vec3A;

use super::{Bvh, OccluderHint, TraversalCounters};
#[cfg(target_arch = "x86_64")]
use super::{NO_NODE, STACK};
#[cfg(target_arch = "x86_64")]
use crate::geometry::bvh::bvh8::{
    decode, is_leaf, slab_overlap_avx2, Avx512BoxTest, BoundedStack, Child, Node8, Stack,
    TraversalStack, EXIT_SCALE, WIDTH,
};
#[cfg(target_arch = "x86_64")]
use crate::geometry::bvh::watertight::{lanes, WatertightPacket, WatertightRay};
#[cfg(target_arch = "x86_64")]
use crate::simd::SimdLevel;
use crate::simd::{Kernel, Level};

/// Rays of a packet reaching a leaf from which its triangles are tested against the rays
/// all at once ([`WatertightPacket`]) rather than ray by ray (shadow and closest-hit
/// packets).
#[cfg(target_arch = "x86_64")]
pub(super) const VECTOR_TRIANGLE_LANES: u32 = 6;

/// Largest number of rays [`Bvh::occluded_packet`] traces together: one AVX-512 register
/// of `f32` lanes.
pub const PACKET: usize = 16;

impl Bvh {
    /// Shadow queries for up to [`PACKET`] rays from one `origin` (`directions[l]`,
    /// `tmax[l]`), traced together: each node's children are first tested against the
    /// packet as one interval ray (eight at once), and the boxes that test keeps against
    /// all the packet's rays at once (AVX-512, sixteen lanes); each ray is tested against
    /// the triangles of the leaves its own box tests reach, by the single-ray watertight
    /// test. The box test is [`Node8::intersect`]'s, lane by lane, with the same
    /// operations, so a ray reaches exactly the leaves it reaches alone and every answer
    /// is [`Self::occluded`]'s. Like [`Self::occluded_hinted`], the packet first searches
    /// the node where the previous packet from this origin found an occluder (`hint`).
    /// Bit `l` of the result is set when ray `l` is occluded. Counters count each ray,
    /// each node test once per ray taking part, and each ray's triangle tests. Without
    /// AVX-512 the rays are traced one by one.
    ///
    /// [`Node8::intersect`]: Node8::intersect
    pub fn occluded_packet<const COUNT: bool>(
        &self,
        origin: Vec3A,
        directions: &[Vec3A],
        tmax: &[f32],
        hint: &mut OccluderHint,
        counters: &mut TraversalCounters,
    ) -> u16 {
        assert!(directions.len() <= PACKET && tmax.len() == directions.len());
        crate::simd::dispatch_avx512(OccludedPacket::<COUNT> {
            bvh: self,
            origin,
            directions,
            tmax,
            hint,
            counters,
        })
    }

    /// Whether a packet of `rays` rays runs the AVX-512 kernels in code compiled for `L`
    /// ([`Kernel`]): the AVX-512 level, some rays and a non-empty tree (else its rays go
    /// one by one).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub(super) fn traces_packets<L: Level>(&self, rays: usize) -> bool {
        L::LEVEL == SimdLevel::Avx512 && rays > 0 && !self.blocks.is_empty()
    }

    /// [`Self::occluded_packet`] under AVX-512: the hinted node's subtree, then the tree
    /// without it, for the rays still unanswered.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl,popcnt")]
    fn occluded_packet_avx512<const COUNT: bool>(
        &self,
        packet: &Packet,
        rays: &mut LaneRays,
        hint: &mut OccluderHint,
        counters: &mut TraversalCounters,
    ) -> u16 {
        let mut active = packet.all;
        let mut skip = NO_NODE;
        if (hint.node as usize) < self.tree.nodes.len() {
            self.packet_search::<COUNT>(packet, rays, hint.node, NO_NODE, &mut active, counters);
            if hint.node == 0 || active == 0 {
                return packet.all & !active;
            }
            skip = hint.node;
        }
        if let Some(node) =
            self.packet_search::<COUNT>(packet, rays, 0, skip, &mut active, counters)
        {
            hint.node = self.hint_node(node);
        }
        packet.all & !active
    }

    /// [`Self::packet_subtree`] with the fixed stack where the tree is shallow enough for it
    /// (see [`BoundedStack`]).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl,popcnt")]
    fn packet_search<const COUNT: bool>(
        &self,
        packet: &Packet,
        rays: &mut LaneRays,
        start: u32,
        skip: u32,
        active: &mut u16,
        counters: &mut TraversalCounters,
    ) -> Option<u32> {
        if self.stack_is_bounded() {
            type Bounded = BoundedStack<(u32, u16, u32), STACK>;
            type Single = BoundedStack<(u32, u32), STACK>;
            self.packet_subtree::<COUNT, Bounded, Single>(
                packet, rays, start, skip, active, counters,
            )
        } else {
            type Spilling = Stack<(u32, u16, u32), STACK>;
            type Single = Stack<(u32, u32), STACK>;
            self.packet_subtree::<COUNT, Spilling, Single>(
                packet, rays, start, skip, active, counters,
            )
        }
    }

    /// Any-hit search of the subtree under node `start`, not entering node `skip`, for the
    /// rays of `active`; clears the bits of those found occluded and returns the node whose
    /// leaf held the first occluder, if any. Leaves are requested and stacked as in
    /// [`Self::occluder_walk`] (entries: child reference, lanes, and the leaf's node).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl,popcnt")]
    fn packet_subtree<
        const COUNT: bool,
        S: TraversalStack<(u32, u16, u32)>,
        S1: TraversalStack<(u32, u32)>,
    >(
        &self,
        packet: &Packet,
        rays: &mut LaneRays,
        start: u32,
        skip: u32,
        active: &mut u16,
        counters: &mut TraversalCounters,
    ) -> Option<u32> {
        let (mut nodes, mut tests) = (0u64, 0u64);
        let mut occluder = None;
        let mut stack = S::new();
        let lane_tmax = lanes(packet.tmax);
        let large = self.tree.outgrows_l2();
        stack.push((start, *active, NO_NODE));
        'trace: while let Some((entry, lanes, holder)) = stack.pop() {
            let lanes = lanes & *active;
            if lanes == 0 {
                continue;
            }
            let node = match decode(entry) {
                // In trees larger than L2, a subtree that one lane reaches is searched
                // by that lane's single ray: its eight-child box test is exact, where the
                // packet's interval test keeps children no lane hits (four in ten of
                // them), and many of garden's packet node visits are by one lane (it
                // gains there, and loses on cornell's small tree, so not there).
                Child::Node(node) if large && lanes.count_ones() == 1 => {
                    let l = lanes.trailing_zeros() as usize % PACKET;
                    let r = self.local_ray(rays.origin, rays.directions[l], rays.tmax[l]);
                    // SAFETY: the CPU has AVX-512 F and VL (this function's contract).
                    let box_test = unsafe { Avx512BoxTest::new() };
                    if let Some(holder) =
                        self.occluder_walk::<COUNT, S1>(&r, node, skip, counters, box_test)
                    {
                        *active &= !lanes;
                        occluder.get_or_insert(holder);
                        if *active == 0 {
                            break 'trace;
                        }
                    }
                    continue;
                }
                Child::Node(node) => node,
                Child::Leaf { first, count } => {
                    let block = &self.blocks[first as usize];
                    if COUNT {
                        tests += count as u64 * lanes.count_ones() as u64;
                    }
                    let mut occluded = 0u16;
                    if lanes.count_ones() >= VECTOR_TRIANGLE_LANES {
                        for t in 0..count as usize {
                            occluded |=
                                packet
                                    .watertight
                                    .hits(block, t, packet.tmax, lanes & !occluded);
                        }
                    } else {
                        let mut rest = lanes;
                        while rest != 0 {
                            let l = rest.trailing_zeros() as usize;
                            rest &= rest - 1;
                            let r = rays.get(&packet.watertight, l);
                            if r.intersect4(block, lane_tmax[l]).0 != 0 {
                                occluded |= 1 << l;
                            }
                        }
                    }
                    if occluded != 0 {
                        *active &= !occluded;
                        occluder.get_or_insert(holder);
                        if *active == 0 {
                            break 'trace;
                        }
                    }
                    continue;
                }
            };
            let n = &self.tree.nodes[node as usize];
            if COUNT {
                nodes += lanes.count_ones() as u64;
            }
            let relative = packet.relative_planes(n);
            let mut touched = packet.children_touched(&relative);
            while touched != 0 {
                let j = touched.trailing_zeros() as usize;
                touched &= touched - 1;
                let r = n.child(j);
                let hit = packet.box_hits(&relative, j, lanes);
                let keep = hit != 0 && r != skip;
                self.request_child(n, r, keep);
                stack.push_if((r, hit, if is_leaf(r) { node } else { NO_NODE }), keep);
            }
        }
        if COUNT {
            counters.nodes += nodes;
            counters.triangles += tests;
        }
        occluder
    }
}

/// [`Bvh::occluded_packet`] as a [`Kernel`]: the packet under AVX-512, else its rays one
/// by one ([`Bvh::occluded_hinted`], which dispatches by itself).
struct OccludedPacket<'a, const COUNT: bool> {
    bvh: &'a Bvh,
    origin: Vec3A,
    directions: &'a [Vec3A],
    tmax: &'a [f32],
    hint: &'a mut OccluderHint,
    counters: &'a mut TraversalCounters,
}

impl<const COUNT: bool> Kernel for OccludedPacket<'_, COUNT> {
    type Output = u16;

    #[inline(always)]
    fn run<L: Level>(self, _level: L) -> u16 {
        let Self {
            bvh,
            origin,
            directions,
            tmax,
            hint,
            counters,
        } = self;
        #[cfg(target_arch = "x86_64")]
        if bvh.traces_packets::<L>(directions.len()) {
            if COUNT {
                counters.rays += directions.len() as u64;
            }
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here the AVX-512 level (F, VL and popcnt among it); 1 to PACKET
            // rays.
            return unsafe {
                let packet = Packet::new(bvh, origin, directions, tmax);
                let rays = &mut LaneRays::new(origin, directions, tmax);
                bvh.occluded_packet_avx512::<COUNT>(&packet, rays, hint, counters)
            };
        }
        let mut occluded = 0u16;
        for (l, (&d, &t)) in directions.iter().zip(tmax).enumerate() {
            if bvh.occluded_hinted::<COUNT>(origin, d, t, hint, counters) {
                occluded |= 1 << l;
            }
        }
        occluded
    }
}

/// A packet's rays as given, for the lanes that continue alone, and their single
/// watertight rays, each prepared when its lane first tests a leaf alone and kept for the
/// packet's later leaves (extracting a lane's ray from the packet's registers at every
/// leaf cost about as much as the triangle test itself).
#[cfg(target_arch = "x86_64")]
pub(super) struct LaneRays<'a> {
    /// The packet's rays as given (one origin).
    origin: Vec3A,
    directions: &'a [Vec3A],
    tmax: &'a [f32],
    /// Left uninitialised until prepared: filling all sixteen up front cost a kilobyte of
    /// stores per packet, as much as a packet of `dynamics`'s short rays takes to trace.
    rays: [std::mem::MaybeUninit<WatertightRay>; PACKET],
    /// The lanes whose ray is prepared.
    ready: u16,
}

#[cfg(target_arch = "x86_64")]
impl<'a> LaneRays<'a> {
    #[inline(always)]
    pub(super) fn new(origin: Vec3A, directions: &'a [Vec3A], tmax: &'a [f32]) -> Self {
        LaneRays {
            origin,
            directions,
            tmax,
            rays: [const { std::mem::MaybeUninit::uninit() }; PACKET],
            ready: 0,
        }
    }

    /// Lane `l`'s ray ([`WatertightPacket::lane_ray`]).
    #[inline(always)]
    pub(super) fn get(&mut self, packet: &WatertightPacket, l: usize) -> &WatertightRay {
        let l = l % PACKET;
        if self.ready >> l & 1 == 0 {
            self.rays[l].write(packet.lane_ray(l));
            self.ready |= 1 << l;
        }
        // SAFETY: lane `l` was written above or when its `ready` bit was set.
        unsafe { self.rays[l].assume_init_ref() }
    }
}

/// A packet of up to [`PACKET`] rays from one origin, prepared for box tests sixteen lanes
/// at a time (see [`Bvh::occluded_packet`]).
#[cfg(target_arch = "x86_64")]
pub(super) struct Packet {
    /// The lanes holding rays.
    pub(super) all: u16,
    origin: [std::arch::x86_64::__m512; 3],
    pub(super) inverse: [std::arch::x86_64::__m512; 3],
    /// Lanes whose direction is negative on each axis: they enter a box by its max plane.
    negative: [std::arch::x86_64::__mmask16; 3],
    /// Per axis, the row of [`Packet::relative_planes`] that every lane enters by and the
    /// row it leaves by, where the lanes agree in sign there (see `mixed_signs`).
    near_row: [usize; 3],
    far_row: [usize; 3],
    /// `tmax · EXIT_SCALE` per lane.
    pub(super) exit: std::arch::x86_64::__m512,
    /// `tmax` per lane (local frame).
    pub(super) tmax: std::arch::x86_64::__m512,
    pub(super) watertight: WatertightPacket,
    /// The packet's rays as one interval ray, for [`Packet::children_touched`]: per axis
    /// the least and greatest inverse direction component over the lanes, and whether
    /// the lanes disagree in sign there.
    inverse_low: [f32; 3],
    inverse_high: [f32; 3],
    mixed_signs: [bool; 3],
    /// The greatest `tmax · EXIT_SCALE` over the lanes.
    exit_high: f32,
}

#[cfg(target_arch = "x86_64")]
impl Packet {
    /// `1..=PACKET` rays. Every lane computes what [`Bvh::local_ray`] computes for its ray,
    /// with the same operations in the same order (so the same bits), sixteen lanes at a
    /// time: preparing the rays one by one took as long as tracing them on cornell.
    #[target_feature(enable = "avx512f")]
    pub(super) fn new(bvh: &Bvh, origin: Vec3A, directions: &[Vec3A], tmax: &[f32]) -> Self {
        use std::arch::x86_64::*;
        let count = directions.len();
        let lane = |l: usize| l.min(count - 1);
        let rows: [[f32; PACKET]; 4] = [
            std::array::from_fn(|l| directions[lane(l)].x),
            std::array::from_fn(|l| directions[lane(l)].y),
            std::array::from_fn(|l| directions[lane(l)].z),
            std::array::from_fn(|l| tmax[lane(l)]),
        ];
        // SAFETY: each row holds PACKET = 16 f32s.
        let [dx, dy, dz, t] = rows.map(|r| unsafe { _mm512_loadu_ps(r.as_ptr()) });
        let splat = _mm512_set1_ps;
        let (mul, add, div) = (_mm512_mul_ps, _mm512_add_ps, _mm512_div_ps);
        // `local_ray`: the direction scaled by `direction_scale`'s powers of two (formed
        // from the exponent bits of the largest magnitude, clamped alike) and the tmax.
        let largest = _mm512_max_ps(
            _mm512_max_ps(_mm512_abs_ps(dx), _mm512_abs_ps(dy)),
            _mm512_abs_ps(dz),
        );
        let biased = _mm512_min_epi32(
            _mm512_max_epi32(
                _mm512_and_si512(
                    _mm512_srli_epi32::<23>(_mm512_castps_si512(largest)),
                    _mm512_set1_epi32(0xff),
                ),
                _mm512_set1_epi32(1),
            ),
            _mm512_set1_epi32(253),
        );
        let power = |exponent: __m512i| _mm512_castsi512_ps(_mm512_slli_epi32::<23>(exponent));
        let scale = power(_mm512_sub_epi32(_mm512_set1_epi32(254), biased));
        let scaled = [mul(dx, scale), mul(dy, scale), mul(dz, scale)];
        let tmax = mul(mul(t, power(biased)), splat(bvh.to_local));
        let o = origin * bvh.to_local;
        // `BoxRay::new`: the inverse of the scaled direction plus +0.0, clamped.
        let inverse = scaled.map(|u| {
            let r = div(splat(1.0), add(u, _mm512_setzero_ps()));
            _mm512_min_ps(_mm512_max_ps(r, splat(-1e30)), splat(1e30))
        });
        // `WatertightRay::new`: the largest axis kz, then kx and ky, swapped when the
        // direction points backwards along kz, and the shear.
        let abs = scaled.map(|u| _mm512_abs_ps(u));
        let gt = |a: __m512, b: __m512| _mm512_cmp_ps_mask::<_CMP_GT_OQ>(a, b);
        let (x_y, x_z, y_z) = (gt(abs[0], abs[1]), gt(abs[0], abs[2]), gt(abs[1], abs[2]));
        let kz_is = [x_y & x_z, !x_y & y_z];
        let pick = |v: [__m512; 3], is: [__mmask16; 2]| {
            _mm512_mask_blend_ps(is[1], _mm512_mask_blend_ps(is[0], v[2], v[0]), v[1])
        };
        let d_kz = pick(scaled, kz_is);
        let backwards = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(d_kz, _mm512_setzero_ps());
        // kx is kz + 1 (mod 3) and ky is kz + 2, or the other way round going backwards.
        let next = [!kz_is[0] & !kz_is[1], kz_is[0]];
        let after = [kz_is[1], !kz_is[0] & !kz_is[1]];
        let swap = |a: [__mmask16; 2], b: [__mmask16; 2]| {
            [0, 1].map(|i| (a[i] & !backwards) | (b[i] & backwards))
        };
        let (kx_is, ky_is) = (swap(next, after), swap(after, next));
        let sz = div(splat(1.0), d_kz);
        let sx = mul(pick(scaled, kx_is), sz);
        let sy = mul(pick(scaled, ky_is), sz);
        // Masks of the lanes where an axis is 1 and where it is 2 (else it is 0).
        let one_two = |is: [__mmask16; 2]| [is[1], !(is[0] | is[1])];
        let (kx_12, ky_12, kz_12) = (one_two(kx_is), one_two(ky_is), one_two(kz_is));
        let exit = mul(tmax, splat(EXIT_SCALE));
        let watertight = WatertightPacket::from_lanes(o, [kx_12, ky_12, kz_12], [sx, sy, sz]);
        let negative = inverse.map(|v| _mm512_cmp_ps_mask::<_CMP_LT_OQ>(v, _mm512_setzero_ps()));
        // Only read on axes where the lanes agree in sign, where any lane is every lane.
        let any_negative = negative.map(|m| m != 0);
        Packet {
            near_row: [0, 1, 2].map(|a| 2 * a + any_negative[a] as usize),
            far_row: [0, 1, 2].map(|a| 2 * a + 1 - any_negative[a] as usize),
            all: (u32::MAX >> (32 - count)) as u16,
            origin: [o.x, o.y, o.z].map(|v| _mm512_set1_ps(v)),
            inverse,
            negative,
            exit_high: _mm512_reduce_max_ps(exit),
            exit,
            tmax,
            watertight,
            inverse_low: inverse.map(|v| _mm512_reduce_min_ps(v)),
            inverse_high: inverse.map(|v| _mm512_reduce_max_ps(v)),
            mixed_signs: negative.map(|m| m != 0 && m != u16::MAX),
        }
    }

    /// The children of `n` whose box some ray of the packet may touch (bit `j` for child
    /// `j`): a superset of the children [`Self::box_hits`] finds for any lane, tested for
    /// all children at once against the interval of the lanes' inverse directions.
    ///
    /// Why it is conservative: the lanes share the origin, so a plane's offset `p - o` is
    /// the same in every lane, and rounded products are monotone in each factor, so
    /// `(p - o) · inv` over the lanes lies between its values at the least and greatest
    /// inverse. The lower ends of the entry terms and the upper ends of the exit terms
    /// then bound every lane's entry from below and exit from above through the same
    /// (monotone) max, min and scaling. On an axis where the lanes' signs differ, their
    /// near planes differ too, and that axis is left unbounded.
    #[target_feature(enable = "avx512f")]
    #[inline]
    pub(super) fn children_touched(&self, relative: &[[f32; WIDTH]; 6]) -> u32 {
        use std::arch::x86_64::*;
        let bound = |axis: usize| {
            // The rows of the lanes' common sign; on an axis of mixed signs the bound
            // is dropped below, whichever rows these are.
            let (near, far) = (self.near_row[axis], self.far_row[axis]);
            let (lo, hi) = (
                _mm256_set1_ps(self.inverse_low[axis]),
                _mm256_set1_ps(self.inverse_high[axis]),
            );
            // SAFETY: each row holds WIDTH = 8 f32s.
            let (n, f) = unsafe {
                (
                    _mm256_loadu_ps(relative[near].as_ptr()),
                    _mm256_loadu_ps(relative[far].as_ptr()),
                )
            };
            let entry = _mm256_min_ps(_mm256_mul_ps(n, lo), _mm256_mul_ps(n, hi));
            let exit = _mm256_max_ps(_mm256_mul_ps(f, lo), _mm256_mul_ps(f, hi));
            if self.mixed_signs[axis] {
                (
                    _mm256_set1_ps(f32::NEG_INFINITY),
                    _mm256_set1_ps(f32::INFINITY),
                )
            } else {
                (entry, exit)
            }
        };
        let (nx, fx) = bound(0);
        let (ny, fy) = bound(1);
        let (nz, fz) = bound(2);
        // SAFETY: AVX-512 F includes AVX2, and this function is compiled for it.
        let (_, touched) = unsafe {
            slab_overlap_avx2([nx, ny, nz], [fx, fy, fz], _mm256_set1_ps(self.exit_high))
        };
        touched
    }

    /// Node `n`'s planes less the packet's origin, `planes[k][j] - origin[k / 2]`: the
    /// offsets that every lane's box test starts from (the lanes share the origin), so
    /// they are computed once per node, eight children at a time, instead of in each lane
    /// of each child's test (bit for bit the same differences).
    #[target_feature(enable = "avx512f")]
    #[inline]
    pub(super) fn relative_planes(&self, n: &Node8) -> [[f32; WIDTH]; 6] {
        use std::arch::x86_64::*;
        let planes = n.planes();
        let mut relative = [[0.0; WIDTH]; 6];
        for (k, row) in relative.iter_mut().enumerate() {
            // The origin's splat, from the lower half of its sixteen-lane register.
            let o = _mm512_castps512_ps256(self.origin[k / 2]);
            // SAFETY: each row holds WIDTH = 8 f32s.
            unsafe {
                let d = _mm256_sub_ps(_mm256_loadu_ps(planes[k].as_ptr()), o);
                _mm256_storeu_ps(row.as_mut_ptr(), d);
            }
        }
        relative
    }

    /// The lanes of `lanes` whose segment touches child `j`'s box, given the node's
    /// [`Self::relative_planes`]: the test of [`Node8::intersect`] with the same operations
    /// in every lane. On an axis where the lanes agree in sign, every lane enters and
    /// leaves by the same planes, and their offsets are splatted without a blend.
    #[target_feature(enable = "avx512f")]
    #[inline]
    pub(super) fn box_hits(&self, relative: &[[f32; WIDTH]; 6], j: usize, lanes: u16) -> u16 {
        self.box_entries(relative, j, lanes, self.exit).0
    }

    /// [`Self::box_hits`] against `exit` (`tmax · EXIT_SCALE` per lane, for rays whose
    /// `tmax` has shrunk to their closest hit so far), with each lane's entry distance.
    #[target_feature(enable = "avx512f")]
    #[inline]
    pub(super) fn box_entries(
        &self,
        relative: &[[f32; WIDTH]; 6],
        j: usize,
        lanes: u16,
        exit: std::arch::x86_64::__m512,
    ) -> (u16, std::arch::x86_64::__m512) {
        use std::arch::x86_64::*;
        // Below WIDTH for the callers' child bits; said so, the row reads need no checks.
        let j = j % WIDTH;
        let slab = |axis: usize| {
            let (near, far) = if self.mixed_signs[axis] {
                let lo = _mm512_set1_ps(relative[2 * axis][j]);
                let hi = _mm512_set1_ps(relative[2 * axis + 1][j]);
                (
                    _mm512_mask_blend_ps(self.negative[axis], lo, hi),
                    _mm512_mask_blend_ps(self.negative[axis], hi, lo),
                )
            } else {
                // SAFETY: `near_row` and `far_row` hold `2 axis` or `2 axis + 1`, below 6.
                let (near, far) = unsafe {
                    (
                        relative.get_unchecked(self.near_row[axis]),
                        relative.get_unchecked(self.far_row[axis]),
                    )
                };
                (_mm512_set1_ps(near[j]), _mm512_set1_ps(far[j]))
            };
            (
                _mm512_mul_ps(near, self.inverse[axis]),
                _mm512_mul_ps(far, self.inverse[axis]),
            )
        };
        let (nx, fx) = slab(0);
        let (ny, fy) = slab(1);
        let (nz, fz) = slab(2);
        let t_near = _mm512_max_ps(
            _mm512_max_ps(_mm512_max_ps(nx, ny), nz),
            _mm512_setzero_ps(),
        );
        let t_far = _mm512_min_ps(
            _mm512_mul_ps(
                _mm512_min_ps(_mm512_min_ps(fx, fy), fz),
                _mm512_set1_ps(EXIT_SCALE),
            ),
            exit,
        );
        (
            _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(lanes, t_near, t_far),
            t_near,
        )
    }
}
