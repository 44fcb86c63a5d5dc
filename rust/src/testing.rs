//! Ray sets and helpers shared by the criterion benches, the Embree peer scripts and the
//! tests, so every comparison traces exactly the same rays. All of them are pure functions
//! of their seed.

use glam::Vec3;

use crate::bsdf::Material;
use crate::geometry::Scene;
use crate::math::{to_world, triangle_cross, uniform_hemisphere};
use crate::sampling::rng::SampleRng;

/// `n` points uniformly distributed by area over the triangles of the objects whose name
/// contains `object_name` (all triangles when none match or `None`), with unit normals
/// flipped into the +y hemisphere. When other objects exist, points are kept only inside
/// their footprint on the xz plane (rejection sampling), so "ground" points lie under the
/// scene's content rather than on bare ground around it. Empty when the scene has no area.
pub fn surface_points(
    scene: &Scene,
    object_name: Option<&str>,
    n: usize,
    seed: u64,
) -> Vec<(Vec3, Vec3)> {
    let mesh = scene.mesh();
    let wanted: Vec<bool> = mesh
        .objects
        .iter()
        .map(|o| object_name.is_none_or(|s| o.name.contains(s)))
        .collect();
    let use_all = !wanted.iter().any(|&w| w);
    let mut cdf = Vec::with_capacity(mesh.triangles.len());
    let mut ids = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0.0f64;
    let mut footprint = crate::geometry::Bounds::EMPTY;
    for (i, t) in mesh.triangles.iter().enumerate() {
        if use_all || wanted[mesh.object_ids[i] as usize] {
            let area = 0.5 * triangle_cross(t).length() as f64;
            if area > 0.0 {
                total += area;
                cdf.push(total);
                ids.push(i);
            }
        } else {
            t.iter().for_each(|v| footprint.grow(*v));
        }
    }
    if ids.is_empty() {
        return Vec::new();
    }
    let inside = |p: Vec3| {
        footprint.is_empty()
            || (p.x >= footprint.min.x
                && p.x <= footprint.max.x
                && p.z >= footprint.min.z
                && p.z <= footprint.max.z)
    };
    let sample = |k: usize, attempt: u64| {
        let rng = SampleRng::new(seed, k as u64, 2 + attempt);
        let target = rng.get(0) as f64 * total;
        let j = cdf.partition_point(|&c| c <= target).min(ids.len() - 1);
        let t = &mesh.triangles[ids[j]];
        // Uniform on the triangle (square-root parameterisation).
        let [a, b] = rng.get2(1);
        let sa = a.sqrt();
        let p = t[0] * (1.0 - sa) + t[1] * (sa * (1.0 - b)) + t[2] * (sa * b);
        let mut nrm = triangle_cross(t).normalize();
        if nrm.y < 0.0 {
            nrm = -nrm;
        }
        (p, nrm)
    };
    (0..n)
        .map(|k| {
            // Bounded retries; the last attempt is kept even outside the footprint.
            (0..64)
                .map(|attempt| sample(k, attempt))
                .find(|(p, _)| inside(*p))
                .unwrap_or_else(|| sample(k, 64))
        })
        .collect()
}

/// Incoherent shadow rays: origins on the objects named like `"ground"` (offset along the
/// normal by [`Scene::offset_point`]), unit directions uniform on the hemisphere around the
/// normal. Returns `(origins, directions)`.
pub fn ground_hemisphere_rays(
    scene: &Scene,
    n: usize,
    seed: u64,
) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    surface_points(scene, Some("ground"), n, seed)
        .into_iter()
        .enumerate()
        .map(|(k, (p, nrm))| {
            let u = SampleRng::new(seed, k as u64, 1).get2(0);
            let d = to_world(uniform_hemisphere(u), nrm);
            let o: [f32; 3] = scene.offset_point(p, nrm).into();
            (o, d.to_array())
        })
        .unzip()
}

/// Record-building bundles: `points` origins on the ground, each with `side * side`
/// directions from a jittered `side x side` grid over its upper hemisphere, point after
/// point, each point's cells in Morton order (as records trace their directions: the
/// coherent workload of visibility records).
pub fn record_bundle_rays(
    scene: &Scene,
    points: usize,
    side: usize,
    seed: u64,
) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let mut origins = Vec::with_capacity(points * side * side);
    let mut dirs = Vec::with_capacity(points * side * side);
    let mut cells: Vec<usize> = (0..side * side).collect();
    cells.sort_by_key(|&j| {
        crate::sampling::octahedral::morton_encode((j % side) as u32, (j / side) as u32)
    });
    for (k, (p, nrm)) in surface_points(scene, Some("ground"), points, seed)
        .into_iter()
        .enumerate()
    {
        let o = scene.offset_point(p, nrm);
        for &j in &cells {
            let jit = SampleRng::new(seed, k as u64, 1 + j as u64).get2(0);
            let u = [
                ((j / side) as f32 + jit[0]) / side as f32,
                ((j % side) as f32 + jit[1]) / side as f32,
            ];
            origins.push(o.into());
            dirs.push(to_world(uniform_hemisphere(u), nrm).into());
        }
    }
    (origins, dirs)
}

/// A record with pseudo-random visibility (each bit 1 with probability `open`, from
/// `seed`) at `position` with unit `normal`, for cache tests and benches that need many
/// records without tracing them. `A` is the visible fraction, `R_i` is 1.
pub fn synthetic_record(
    m: u32,
    position: Vec3,
    normal: Vec3,
    open: f64,
    seed: u64,
) -> crate::visibility::Record {
    use crate::sampling::rng::{hash4, to_unit_f64};
    let bits = crate::visibility::VisibilityBits::from_fn(m, |z| {
        to_unit_f64(hash4(seed, z as u64, 0, 0)) < open
    })
    .expect("m in 1..=7");
    crate::visibility::Record {
        position,
        normal,
        ambient_occlusion: bits.view().visible_fraction(),
        bits,
        nearest_hit_distance: 1.0,
        misses: 0,
        uses: 0,
        last_frame: 0,
    }
}

/// Damaged copy number `k` of `bytes` for fuzzing file readers: cut short, bits flipped,
/// random bytes inserted, a block duplicated, or a 4-byte field near the start zeroed or
/// set to all ones. A pure function of `(bytes, k, seed)`.
pub fn damaged(bytes: &[u8], k: u64, seed: u64) -> Vec<u8> {
    let rng = SampleRng::new(seed, k, 7);
    let mut d = 0;
    let mut below = |n: usize| {
        d += 1;
        ((rng.get(d) as f64 * n as f64) as usize).min(n.saturating_sub(1))
    };
    let mut b = bytes.to_vec();
    let n = b.len().max(1);
    match k % 5 {
        0 => b.truncate(below(n)),
        1 => {
            for _ in 0..1 + below(8) {
                let at = below(n);
                if let Some(x) = b.get_mut(at) {
                    *x ^= 1 << below(8);
                }
            }
        }
        2 => {
            let at = below(n).min(b.len());
            let junk: Vec<u8> = (0..1 + below(64)).map(|_| below(256) as u8).collect();
            b.splice(at..at, junk);
        }
        3 => {
            let at = below(n).min(b.len());
            let end = (at + 1 + below(256)).min(b.len());
            let block = b[at..end].to_vec();
            b.splice(at..at, block);
        }
        _ => {
            let at = below(n.min(128)).min(b.len());
            let end = (at + 4).min(b.len());
            let value = if below(2) == 0 { 0 } else { 0xff };
            b[at..end].iter_mut().for_each(|x| *x = value);
        }
    }
    b
}

/// The furnace of the indirect-light tests: the inside of a closed sphere of radius 1 at
/// the origin (an icosphere of `subdivisions`), of `material`, whose triangles face and
/// emit radiance 1 inwards. Two points of it see each other with `G = 1 / (4 r²)`, so
/// light bounces between them without `1/d²` spikes, and each bounce keeps the
/// material's directional albedo.
pub fn furnace_sphere(subdivisions: u32, material: Material) -> Scene {
    let mut tris = Vec::new();
    crate::scenes::shapes::icosphere(&mut tris, Vec3::ZERO, 1.0, subdivisions);
    // Inward winding, so the emission faces the centre.
    for t in &mut tris {
        t.swap(1, 2);
    }
    let v: Vec<[f32; 3]> = tris.iter().flatten().map(|v| v.to_array()).collect();
    let f: Vec<[i64; 3]> = (0..tris.len() as i64)
        .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
        .collect();
    let mut scene = Scene::new();
    let id = scene
        .add_indexed(&v, &f, material, None)
        .expect("an icosphere is a valid mesh");
    scene
        .set_emitter(id, [1.0; 3])
        .expect("an icosphere has area");
    scene
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::orthonormal_basis;

    #[test]
    fn basis_is_orthonormal_everywhere() {
        for n in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            Vec3::new(0.3, -0.5, 0.8).normalize(),
            Vec3::new(0.0, 0.0, -1e-9).normalize(),
        ] {
            let (t, b) = orthonormal_basis(n);
            for (x, y) in [(t, b), (t, n), (b, n)] {
                assert!(x.dot(y).abs() < 1e-5);
            }
            assert!((t.length() - 1.0).abs() < 1e-5 && (b.length() - 1.0).abs() < 1e-5);
            assert!((t.cross(b) - n).length() < 1e-5, "right-handed");
        }
    }

    #[test]
    fn hemisphere_directions_have_the_right_mean() {
        // E[z] = 1/2 for the uniform hemisphere; standard error ~ 0.29 / sqrt(n).
        let n = 100_000;
        let mean: f64 = (0..n)
            .map(|i| uniform_hemisphere(SampleRng::new(0, i, 0).get2(0)).z as f64)
            .sum::<f64>()
            / n as f64;
        assert!(
            (mean - 0.5).abs() < 4.0 * 0.2887 / (n as f64).sqrt(),
            "{mean}"
        );
    }

    #[test]
    fn surface_points_lie_on_the_named_object() {
        let mut s = Scene::new();
        let q = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
        ];
        let m = crate::bsdf::Material::DEFAULT;
        s.add_indexed(&q, &[[0, 2, 1], [0, 3, 2]], m, Some("ground".into()))
            .unwrap();
        let wall = [[0.0, 0.0, 5.0], [1.0, 0.0, 5.0], [1.0, 1.0, 5.0]];
        s.add_indexed(&wall, &[[0, 1, 2]], m, Some("wall".into()))
            .unwrap();
        let pts = surface_points(&s, Some("ground"), 1000, 3);
        assert!(pts
            .iter()
            .all(|(p, n)| p.y == 0.0 && *n == Vec3::Y && p.z <= 1.0));
        let (o, d) = record_bundle_rays(&s, 2, 4, 1);
        assert_eq!((o.len(), d.len()), (32, 32));
        assert!(d.iter().all(|d| d[1] >= 0.0));
        assert!(o.iter().all(|o| o[1] > 0.0), "offset above the ground");
    }
}
