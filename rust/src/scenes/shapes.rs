//! Mesh-building helpers shared by the built-in scenes.
//!
//! Every helper appends triangles to a `Vec<[Vec3; 3]>` and winds them counter-clockwise
//! seen from the side that the documented normal points to, i.e. the geometric normal
//! `(v1 - v0) x (v2 - v0)` is the documented one. Closed shapes ([`BoxGrid::closed`],
//! capped [`tube`]s, [`icosphere`]s, [`lathe`]s whose profile starts and ends on the axis)
//! are watertight: every shared edge is computed from the same inputs by the same
//! arithmetic, so its vertices are bit-identical on both sides and there are no
//! T-junctions. Lengths are in metres.

use std::f32::consts::TAU;

use glam::{Affine3A, Quat, Vec3};

use crate::sampling::rng::{hash4, to_unit_f32};

/// A triangle as three world-space vertices.
pub type Tri = [Vec3; 3];

/// Largest number of sides of a [`tube`] or [`lathe`] (rings live on the stack).
pub const MAX_SIDES: usize = 64;

/// Largest number of cells along one side of a [`grid`] or [`BoxGrid`] face.
pub const MAX_CELLS: usize = 4096;

/// Largest [`icosphere`] subdivision level (20 * 4^8 = 1.3M triangles).
pub const MAX_ICO_LEVEL: u32 = 8;

/// Uniform in `[0, 1)`: a pure function of `(seed, index, stream, dim)` (see
/// [`crate::sampling::rng`]). Scenes use `index` for the item (blade, curve), `stream` for
/// the step along it and `dim` for the coordinate.
#[inline]
pub fn uniform(seed: u64, index: u64, stream: u64, dim: u64) -> f32 {
    to_unit_f32(hash4(seed, index, stream, dim))
}

/// Uniform unit vector from two uniforms in `[0, 1)`.
#[inline]
pub fn sphere_dir(u: f32, v: f32) -> Vec3 {
    let z = 1.0 - 2.0 * u;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = (TAU * v).sin_cos();
    Vec3::new(r * c, r * s, z)
}

/// Number of cells of length at most `cell` that cover `length`: at least 1, at most
/// [`MAX_CELLS`] (also for NaN or infinite inputs).
pub fn cells(length: f32, cell: f32) -> usize {
    let n = (length / cell).ceil();
    if n.is_finite() && n >= 1.0 {
        (n as usize).min(MAX_CELLS)
    } else if n.is_infinite() && n > 0.0 {
        MAX_CELLS
    } else {
        1
    }
}

/// `n + 1` evenly spaced values from `lo` to `hi`; both ends are exact.
pub fn lattice(lo: f32, hi: f32, n: usize) -> Vec<f32> {
    let n = n.max(1);
    (0..=n)
        .map(|i| {
            if i == n {
                hi
            } else {
                lo + (hi - lo) * (i as f32 / n as f32)
            }
        })
        .collect()
}

/// Quad `a b c d` (counter-clockwise seen from the front) as triangles `abc`, `acd`.
#[inline]
pub fn quad(out: &mut Vec<Tri>, a: Vec3, b: Vec3, c: Vec3, d: Vec3) {
    out.push([a, b, c]);
    out.push([a, c, d]);
}

/// Parallelogram `origin + s u + t v` (`s, t` in [0, 1]) cut into `nu x nv` cells of two
/// triangles each; normal along `u x v`.
pub fn grid(out: &mut Vec<Tri>, origin: Vec3, u: Vec3, v: Vec3, nu: usize, nv: usize) {
    let (nu, nv) = (nu.clamp(1, MAX_CELLS), nv.clamp(1, MAX_CELLS));
    let (su, sv) = (lattice(0.0, 1.0, nu), lattice(0.0, 1.0, nv));
    let p = |i: usize, j: usize| origin + u * su[i] + v * sv[j];
    out.reserve(2 * nu * nv);
    for j in 0..nv {
        for i in 0..nu {
            quad(out, p(i, j), p(i + 1, j), p(i + 1, j + 1), p(i, j + 1));
        }
    }
}

/// Horizontal square of side `size` centred at `center` (at height `center.y`), cut into
/// `n x n` cells; normal +y. `2 n^2` triangles.
pub fn ground(out: &mut Vec<Tri>, center: Vec3, size: f32, n: usize) {
    let origin = center - Vec3::new(size, 0.0, size) * 0.5;
    grid(out, origin, Vec3::Z * size, Vec3::X * size, n, n);
}

/// Horizontal lattice at height `y` over the coordinates `xs` x `zs` (each increasing, at
/// least two values); normal +y. `2 (xs.len() - 1) (zs.len() - 1)` triangles.
pub fn ground_lattice(out: &mut Vec<Tri>, xs: &[f32], zs: &[f32], y: f32) {
    out.reserve(2 * xs.len().saturating_sub(1) * zs.len().saturating_sub(1));
    for x in xs.windows(2) {
        for z in zs.windows(2) {
            quad(
                out,
                Vec3::new(x[0], y, z[0]),
                Vec3::new(x[0], y, z[1]),
                Vec3::new(x[1], y, z[1]),
                Vec3::new(x[1], y, z[0]),
            );
        }
    }
}

/// Coordinates from `-outer` to `outer`: cells of at most `cell` over `[-inner, inner]`,
/// then cells growing by `growth` (> 1) per step out to `outer` on both sides
/// (symmetric). For a ground that reaches the horizon without many triangles.
pub fn graded(inner: f32, cell: f32, outer: f32, growth: f32) -> Vec<f32> {
    // An even number of core cells, so 0 is a vertex and the two sides mirror exactly.
    let half = cells(2.0 * inner, cell).div_ceil(2).min(MAX_CELLS / 2);
    let mut pos: Vec<f32> = (1..=half)
        .map(|k| {
            if k == half {
                inner
            } else {
                inner * (k as f32 / half as f32)
            }
        })
        .collect();
    let growth = growth.max(1.01);
    let (mut at, mut step) = (inner, inner / half as f32 * growth);
    while at < outer && pos.len() < MAX_CELLS {
        at += step;
        step *= growth;
        // Merge a last sliver into the previous cell.
        if at + step * 0.25 >= outer {
            at = outer;
        }
        pos.push(at.min(outer));
    }
    let mut out: Vec<f32> = pos.iter().rev().map(|v| -v).collect();
    out.push(0.0);
    out.extend_from_slice(&pos);
    out
}

/// A face of a box, named by its outward normal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Face {
    NegX,
    PosX,
    NegY,
    PosY,
    NegZ,
    PosZ,
}

impl Face {
    /// All six faces.
    pub const ALL: [Face; 6] = [
        Face::NegX,
        Face::PosX,
        Face::NegY,
        Face::PosY,
        Face::NegZ,
        Face::PosZ,
    ];

    /// Axis of the outward normal (0 = x, 1 = y, 2 = z).
    pub const fn axis(self) -> usize {
        match self {
            Face::NegX | Face::PosX => 0,
            Face::NegY | Face::PosY => 1,
            Face::NegZ | Face::PosZ => 2,
        }
    }

    /// True when the outward normal points along the positive axis.
    pub const fn positive(self) -> bool {
        matches!(self, Face::PosX | Face::PosY | Face::PosZ)
    }
}

/// A box whose faces are cut into a lattice of cells, optionally turned and moved by a rigid
/// transform. All faces share one lattice per axis, so edges between faces match exactly.
#[derive(Clone, Debug)]
pub struct BoxGrid {
    coords: [Vec<f32>; 3],
    transform: Affine3A,
}

impl BoxGrid {
    /// Axis-aligned box `[min, max]` with every side cut into cells at most `cell` long.
    pub fn new(min: Vec3, max: Vec3, cell: f32) -> Self {
        let axis = |k: usize| lattice(min[k], max[k], cells(max[k] - min[k], cell));
        Self {
            coords: [axis(0), axis(1), axis(2)],
            transform: Affine3A::IDENTITY,
        }
    }

    /// A box of `size` centred at `center`, turned by `yaw` radians about +y
    /// (counter-clockwise seen from above), cells at most `cell` long.
    pub fn centered(center: Vec3, size: Vec3, yaw: f32, cell: f32) -> Self {
        let mut b = Self::new(-size * 0.5, size * 0.5, cell);
        b.transform = Affine3A::from_rotation_translation(Quat::from_rotation_y(yaw), center);
        b
    }

    /// Cells along each axis.
    pub fn cells(&self) -> [usize; 3] {
        self.coords.clone().map(|c| c.len() - 1)
    }

    /// Triangles of one face.
    pub fn face_triangles(&self, face: Face) -> usize {
        let k = face.axis();
        let c = self.cells();
        2 * c[(k + 1) % 3] * c[(k + 2) % 3]
    }

    /// Appends one face; its normal points out of the box, or into it with `inward`.
    pub fn face(&self, out: &mut Vec<Tri>, face: Face, inward: bool) {
        let k = face.axis();
        let (a, b) = ((k + 1) % 3, (k + 2) % 3);
        let (cu, cv) = (&self.coords[a], &self.coords[b]);
        let ck = if face.positive() {
            self.coords[k][self.coords[k].len() - 1]
        } else {
            self.coords[k][0]
        };
        // Quads (i, j) -> (i+1, j) -> (i+1, j+1) -> (i, j+1) face +e_k since e_a x e_b = e_k.
        let reverse = face.positive() == inward;
        let p = |i: usize, j: usize| {
            let mut q = [0.0f32; 3];
            q[k] = ck;
            q[a] = cu[i];
            q[b] = cv[j];
            self.transform.transform_point3(Vec3::from(q))
        };
        out.reserve(self.face_triangles(face));
        for j in 0..cv.len() - 1 {
            for i in 0..cu.len() - 1 {
                let (p00, p10, p11, p01) = (p(i, j), p(i + 1, j), p(i + 1, j + 1), p(i, j + 1));
                if reverse {
                    quad(out, p00, p01, p11, p10);
                } else {
                    quad(out, p00, p10, p11, p01);
                }
            }
        }
    }

    /// Appends the given faces (see [`BoxGrid::face`]).
    pub fn faces(&self, out: &mut Vec<Tri>, faces: &[Face], inward: bool) {
        for &f in faces {
            self.face(out, f, inward);
        }
    }

    /// Appends all six faces, normals outward: a closed, watertight box.
    pub fn closed(&self, out: &mut Vec<Tri>) {
        self.faces(out, &Face::ALL, false);
    }
}

/// A rectangular hole in a wall: `u` along the wall, `v` up (both in world units, absolute).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Opening {
    pub u: [f32; 2],
    pub v: [f32; 2],
}

/// Splits a wall slab into boxes around rectangular openings. The wall runs along axis
/// `along` (0 = x or 2 = z) over `u`, from height `v[0]` to `v[1]`, and spans `w` across
/// (the other horizontal axis). Openings must lie inside the wall and not overlap in `u`.
/// Returns `(min, max)` corners of the pieces: full-height piers between openings, plus a
/// sill below and a lintel above each opening (when they have non-zero height).
pub fn wall_pieces(
    along: usize,
    u: [f32; 2],
    v: [f32; 2],
    w: [f32; 2],
    openings: &[Opening],
) -> Vec<(Vec3, Vec3)> {
    let across = 2 - along;
    let piece = |u0: f32, u1: f32, v0: f32, v1: f32| {
        let (mut lo, mut hi) = (Vec3::ZERO, Vec3::ZERO);
        lo[along] = u0;
        hi[along] = u1;
        lo[1] = v0;
        hi[1] = v1;
        lo[across] = w[0];
        hi[across] = w[1];
        (lo, hi)
    };
    let mut sorted = openings.to_vec();
    sorted.sort_by(|a, b| a.u[0].total_cmp(&b.u[0]));
    let mut out = Vec::new();
    let mut at = u[0];
    for o in &sorted {
        if o.u[0] > at {
            out.push(piece(at, o.u[0], v[0], v[1]));
        }
        if o.v[0] > v[0] {
            out.push(piece(o.u[0], o.u[1], v[0], o.v[0]));
        }
        if o.v[1] < v[1] {
            out.push(piece(o.u[0], o.u[1], o.v[1], v[1]));
        }
        at = o.u[1];
    }
    if u[1] > at {
        out.push(piece(at, u[1], v[0], v[1]));
    }
    out
}

#[inline]
fn ring(dst: &mut [Vec3], center: Vec3, n: Vec3, b: Vec3, radius: f32, trig: &[(f32, f32)]) {
    for (d, &(s, c)) in dst.iter_mut().zip(trig) {
        *d = if radius == 0.0 {
            center
        } else {
            center + (n * c + b * s) * radius
        };
    }
}

/// Joins two rings of equal length (angles increasing counter-clockwise about the
/// direction from `a` to `b`): normals face away from the axis. A ring collapsed to a point
/// gives one triangle per side instead of two (no degenerate triangles).
#[inline]
fn band(out: &mut Vec<Tri>, a: &[Vec3], b: &[Vec3], a_point: bool, b_point: bool) {
    let s = a.len();
    for j in 0..s {
        let k = if j + 1 == s { 0 } else { j + 1 };
        if !a_point {
            out.push([a[j], a[k], b[k]]);
        }
        if !b_point {
            out.push([a[j], b[k], b[j]]);
        }
    }
}

/// Fan over a ring; with `toward_axis_end` the normal is `n x b` (the ring's axis
/// direction), otherwise the opposite.
#[inline]
fn cap(out: &mut Vec<Tri>, r: &[Vec3], toward_axis_end: bool) {
    for j in 1..r.len() - 1 {
        if toward_axis_end {
            out.push([r[0], r[j], r[j + 1]]);
        } else {
            out.push([r[0], r[j + 1], r[j]]);
        }
    }
}

fn trig_table(sides: usize) -> [(f32, f32); MAX_SIDES] {
    let mut t = [(0.0, 1.0); MAX_SIDES];
    for (j, e) in t.iter_mut().enumerate().take(sides) {
        *e = (TAU * j as f32 / sides as f32).sin_cos();
    }
    t
}

/// Triangles that [`tube`] makes for `points` points.
pub const fn tube_triangles(points: usize, sides: usize, caps: bool) -> usize {
    if points < 2 {
        return 0;
    }
    let s = if sides < 3 {
        3
    } else if sides > MAX_SIDES {
        MAX_SIDES
    } else {
        sides
    };
    2 * s * (points - 1) + if caps { 2 * (s - 2) } else { 0 }
}

/// A tube of constant `radius` along the polyline `points`, with `sides` sides (clamped to
/// `3..=MAX_SIDES`) and optional flat end caps (closed when `caps`). Rings are
/// perpendicular to the local tangent and framed by parallel transport, so the tube does
/// not twist. Normals face outward. Fewer than two points give nothing. See
/// [`tube_triangles`] for the count.
pub fn tube(out: &mut Vec<Tri>, points: &[Vec3], radius: f32, sides: usize, caps: bool) {
    let n = points.len();
    if n < 2 {
        return;
    }
    let sides = sides.clamp(3, MAX_SIDES);
    let trig = trig_table(sides);
    let trig = &trig[..sides];
    let mut t = Vec3::Y;
    let mut tangent = |i: usize| {
        let d = points[(i + 1).min(n - 1)] - points[i.saturating_sub(1)];
        t = d.normalize_or(t);
        t
    };
    let t0 = tangent(0);
    let mut nrm = t0.any_orthonormal_vector();
    let (mut prev, mut cur) = ([Vec3::ZERO; MAX_SIDES], [Vec3::ZERO; MAX_SIDES]);
    ring(
        &mut prev[..sides],
        points[0],
        nrm,
        t0.cross(nrm),
        radius,
        trig,
    );
    out.reserve(tube_triangles(n, sides, caps));
    if caps {
        cap(out, &prev[..sides], false);
    }
    for (i, &p) in points.iter().enumerate().skip(1) {
        let ti = tangent(i);
        nrm = (nrm - ti * nrm.dot(ti)).normalize_or(ti.any_orthonormal_vector());
        ring(&mut cur[..sides], p, nrm, ti.cross(nrm), radius, trig);
        band(out, &prev[..sides], &cur[..sides], false, false);
        std::mem::swap(&mut prev, &mut cur);
    }
    if caps {
        cap(out, &prev[..sides], true);
    }
}

/// Surface of revolution about the axis through `base` along unit `axis`. `profile` holds
/// `(radius, height)` pairs; with increasing heights the normals face away from the axis.
/// A radius of 0 closes the surface at that end with a point (a profile starting and
/// ending at radius 0 gives a closed solid). `sides` is clamped to `3..=MAX_SIDES`.
pub fn lathe(out: &mut Vec<Tri>, base: Vec3, axis: Vec3, profile: &[(f32, f32)], sides: usize) {
    if profile.len() < 2 {
        return;
    }
    let sides = sides.clamp(3, MAX_SIDES);
    let trig = trig_table(sides);
    let trig = &trig[..sides];
    let nrm = axis.any_orthonormal_vector();
    let bin = axis.cross(nrm);
    let (mut prev, mut cur) = ([Vec3::ZERO; MAX_SIDES], [Vec3::ZERO; MAX_SIDES]);
    let (r0, h0) = profile[0];
    ring(&mut prev[..sides], base + axis * h0, nrm, bin, r0, trig);
    let mut prev_point = r0 == 0.0;
    for &(r, h) in &profile[1..] {
        ring(&mut cur[..sides], base + axis * h, nrm, bin, r, trig);
        band(out, &prev[..sides], &cur[..sides], prev_point, r == 0.0);
        std::mem::swap(&mut prev, &mut cur);
        prev_point = r == 0.0;
    }
}

/// A strip through the `spine` points, `half_widths[i]` to either side along `side`: one
/// quad (two triangles) per segment, one triangle where an end has width 0. The normal is
/// roughly `side x (spine direction)`.
pub fn strip(out: &mut Vec<Tri>, spine: &[Vec3], half_widths: &[f32], side: Vec3) {
    for i in 0..spine.len().min(half_widths.len()).saturating_sub(1) {
        let (p0, p1) = (spine[i], spine[i + 1]);
        let (w0, w1) = (half_widths[i], half_widths[i + 1]);
        let (l0, r0, l1, r1) = (
            p0 - side * w0,
            p0 + side * w0,
            p1 - side * w1,
            p1 + side * w1,
        );
        match (w0 == 0.0, w1 == 0.0) {
            (true, true) => {}
            (true, false) => out.push([p0, r1, l1]),
            (false, true) => out.push([l0, r0, p1]),
            (false, false) => quad(out, l0, r0, r1, l1),
        }
    }
}

const ICO_VERTICES: [[f32; 3]; 12] = {
    const T: f32 = 1.618_034; // golden ratio
    [
        [-1.0, T, 0.0],
        [1.0, T, 0.0],
        [-1.0, -T, 0.0],
        [1.0, -T, 0.0],
        [0.0, -1.0, T],
        [0.0, 1.0, T],
        [0.0, -1.0, -T],
        [0.0, 1.0, -T],
        [T, 0.0, -1.0],
        [T, 0.0, 1.0],
        [-T, 0.0, -1.0],
        [-T, 0.0, 1.0],
    ]
};

const ICO_FACES: [[usize; 3]; 20] = [
    [0, 11, 5],
    [0, 5, 1],
    [0, 1, 7],
    [0, 7, 10],
    [0, 10, 11],
    [1, 5, 9],
    [5, 11, 4],
    [11, 10, 2],
    [10, 7, 6],
    [7, 1, 8],
    [3, 9, 4],
    [3, 4, 2],
    [3, 2, 6],
    [3, 6, 8],
    [3, 8, 9],
    [4, 9, 5],
    [2, 4, 11],
    [6, 2, 10],
    [8, 6, 7],
    [9, 8, 1],
];

/// Triangles of an [`icosphere`] of `level`.
pub const fn icosphere_triangles(level: u32) -> usize {
    let l = if level > MAX_ICO_LEVEL {
        MAX_ICO_LEVEL
    } else {
        level
    };
    20 << (2 * l)
}

/// Sphere approximated by an icosahedron whose faces are split in four `level` times
/// (clamped to [`MAX_ICO_LEVEL`]); `20 * 4^level` triangles, closed, normals outward.
pub fn icosphere(out: &mut Vec<Tri>, center: Vec3, radius: f32, level: u32) {
    fn split(out: &mut Vec<Tri>, c: Vec3, r: f32, t: [Vec3; 3], level: u32) {
        if level == 0 {
            out.push(t.map(|v| c + v * r));
            return;
        }
        let [a, b, d] = t;
        // (x + y) is commutative, so the neighbour across an edge gets the same midpoint.
        let (ab, bd, da) = (
            (a + b).normalize(),
            (b + d).normalize(),
            (d + a).normalize(),
        );
        split(out, c, r, [a, ab, da], level - 1);
        split(out, c, r, [ab, b, bd], level - 1);
        split(out, c, r, [da, bd, d], level - 1);
        split(out, c, r, [ab, bd, da], level - 1);
    }
    let level = level.min(MAX_ICO_LEVEL);
    out.reserve(icosphere_triangles(level));
    for f in ICO_FACES {
        let t = f.map(|i| Vec3::from(ICO_VERTICES[i]).normalize());
        split(out, center, radius, t, level);
    }
}

/// A closed bumpy ellipsoid: an [`icosphere`] of `level` whose unit directions `v` are
/// pushed out to `v (1 + bump(v))`, `bump` a sum of six sines of random frequencies (2 to 9
/// per radian), phases (from `seed`) and total amplitude `amplitude` (a fraction of the
/// radius), then scaled by `radii` about `center`. Vertices shared by triangles are
/// bit-identical before and after, so the mesh stays closed; it lies within `radii (1 +
/// amplitude)` of `center` per axis.
pub fn bumpy_ellipsoid(
    out: &mut Vec<Tri>,
    center: Vec3,
    radii: Vec3,
    level: u32,
    amplitude: f32,
    seed: u64,
) {
    let mut t = Vec::new();
    icosphere(&mut t, Vec3::ZERO, 1.0, level);
    let waves: Vec<(Vec3, f32)> = (0..6u64)
        .map(|k| {
            let u = |d: u64| uniform(seed, k, 0, d);
            let axis = sphere_dir(u(0), u(1));
            (axis * (2.0 + 7.0 * u(2)), std::f32::consts::TAU * u(3))
        })
        .collect();
    let displace = |v: Vec3| {
        let bump: f32 = waves
            .iter()
            .map(|(f, phase)| (f.dot(v) + phase).sin())
            .sum::<f32>()
            * (amplitude / 6.0);
        center + v * (1.0 + bump) * radii
    };
    out.extend(t.iter().map(|tri| tri.map(displace)));
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::collections::HashMap;

    type Key = [u32; 3];
    fn key(v: Vec3) -> Key {
        v.to_array().map(f32::to_bits)
    }

    /// Every directed edge appears exactly once and its reverse exactly once: a closed,
    /// consistently oriented surface without T-junctions.
    pub(crate) fn assert_closed(tris: &[Tri]) {
        let mut edges: HashMap<(Key, Key), i32> = HashMap::new();
        for t in tris {
            assert_ne!(
                (t[1] - t[0]).cross(t[2] - t[0]),
                Vec3::ZERO,
                "degenerate {t:?}"
            );
            for k in 0..3 {
                *edges.entry((key(t[k]), key(t[(k + 1) % 3]))).or_default() += 1;
            }
        }
        for (&(a, b), &n) in &edges {
            assert_eq!(n, 1, "edge used {n} times");
            assert_eq!(edges.get(&(b, a)), Some(&1), "edge without a twin");
        }
    }

    /// Signed volume (divergence theorem): positive when normals face outward.
    fn volume(tris: &[Tri]) -> f32 {
        tris.iter().map(|t| t[0].dot(t[1].cross(t[2])) / 6.0).sum()
    }

    #[test]
    fn boxes_are_closed_and_outward() {
        let mut t = Vec::new();
        let b = BoxGrid::centered(Vec3::new(1.0, 2.0, 3.0), Vec3::new(1.0, 2.0, 0.5), 0.3, 0.3);
        b.closed(&mut t);
        assert_eq!(b.cells(), [4, 7, 2]);
        assert_eq!(t.len(), 2 * 2 * (4 * 7 + 7 * 2 + 2 * 4));
        assert_closed(&t);
        assert!((volume(&t) - 1.0).abs() < 1e-4, "{}", volume(&t));
        let mut inward = Vec::new();
        b.faces(&mut inward, &Face::ALL, true);
        assert!((volume(&inward) + 1.0).abs() < 1e-4);
    }

    #[test]
    fn ground_and_grid_face_up() {
        let mut t = Vec::new();
        ground(&mut t, Vec3::new(0.0, 1.0, 0.0), 4.0, 3);
        assert_eq!(t.len(), 18);
        for tri in &t {
            let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
            assert!(n.y > 0.0 && n.x == 0.0 && n.z == 0.0);
            assert!(tri.iter().all(|v| v.y == 1.0 && v.x.abs() <= 2.0));
        }
        let area: f32 = t
            .iter()
            .map(|t| (t[1] - t[0]).cross(t[2] - t[0]).length() / 2.0)
            .sum();
        assert!((area - 16.0).abs() < 1e-4);
    }

    #[test]
    fn capped_tubes_and_spheres_are_closed() {
        let pts: Vec<Vec3> = (0..20)
            .map(|i| {
                let s = i as f32 * 0.3;
                Vec3::new(s.cos(), s * 0.2, s.sin())
            })
            .collect();
        let mut t = Vec::new();
        tube(&mut t, &pts, 0.05, 6, true);
        assert_eq!(t.len(), tube_triangles(20, 6, true));
        assert_closed(&t);
        assert!(volume(&t) > 0.0);
        let mut s = Vec::new();
        icosphere(&mut s, Vec3::new(0.5, 1.0, 0.0), 2.0, 3);
        assert_eq!(s.len(), icosphere_triangles(3));
        assert_closed(&s);
        let v = volume(&s);
        let exact = 4.0 / 3.0 * std::f32::consts::PI * 8.0;
        assert!(v > 0.97 * exact && v < exact, "{v}");
        let mut l = Vec::new();
        lathe(
            &mut l,
            Vec3::ZERO,
            Vec3::X,
            &[(0.0, 0.0), (1.0, 0.5), (0.5, 1.0), (0.0, 1.2)],
            8,
        );
        assert_eq!(l.len(), 8 * 4);
        assert_closed(&l);
        assert!(volume(&l) > 0.0);
    }

    #[test]
    fn strips_and_wall_pieces() {
        let mut t = Vec::new();
        strip(
            &mut t,
            &[Vec3::ZERO, Vec3::Y, Vec3::Y * 2.0],
            &[0.1, 0.05, 0.0],
            Vec3::X,
        );
        assert_eq!(t.len(), 3);
        let n = (t[0][1] - t[0][0]).cross(t[0][2] - t[0][0]);
        assert!(n.z > 0.0);
        let pieces = wall_pieces(
            0,
            [0.0, 10.0],
            [0.0, 3.0],
            [1.0, 1.2],
            &[
                Opening {
                    u: [6.0, 7.0],
                    v: [0.0, 2.0],
                },
                Opening {
                    u: [2.0, 4.0],
                    v: [1.0, 2.0],
                },
            ],
        );
        // pier, sill, lintel, pier, (no sill under the door), lintel, pier
        assert_eq!(pieces.len(), 6);
        let area: f32 = pieces.iter().map(|(a, b)| (b.x - a.x) * (b.y - a.y)).sum();
        assert!((area - (30.0 - 2.0 - 2.0)).abs() < 1e-5);
        assert!(pieces.iter().all(|(a, b)| a.z == 1.0 && b.z == 1.2));
    }

    #[test]
    fn graded_grounds_reach_out() {
        let c = graded(20.0, 1.5, 150.0, 1.5);
        assert_eq!((c[0], *c.last().unwrap()), (-150.0, 150.0));
        assert!(c.windows(2).all(|w| w[1] > w[0]));
        assert!(c.contains(&-20.0) && c.contains(&20.0));
        for (a, b) in c.iter().zip(c.iter().rev()) {
            assert_eq!(*a, -*b);
        }
        assert!(c.len() < 50, "{}", c.len());
        let mut t = Vec::new();
        ground_lattice(&mut t, &c, &c, 0.0);
        assert_eq!(t.len(), 2 * (c.len() - 1).pow(2));
        for tri in &t {
            assert!((tri[1] - tri[0]).cross(tri[2] - tri[0]).y > 0.0);
        }
        let area: f32 = t
            .iter()
            .map(|t| (t[1] - t[0]).cross(t[2] - t[0]).length() / 2.0)
            .sum();
        assert!((area / 300.0f32.powi(2) - 1.0).abs() < 1e-4);
    }

    #[test]
    fn cells_is_robust() {
        assert_eq!(cells(1.0, 0.3), 4);
        assert_eq!(cells(1.0, f32::INFINITY), 1);
        assert_eq!(cells(1.0, 0.0), MAX_CELLS);
        assert_eq!(cells(f32::NAN, 1.0), 1);
        assert_eq!(lattice(0.0, 1.0, 3), vec![0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0]);
    }
}
