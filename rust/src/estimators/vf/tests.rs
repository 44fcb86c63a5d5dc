//! VF's stages against brute force, known answers and extremes (issue 63 §2).

use glam::{UVec3, Vec3};

use super::filter::filter;
use super::gather::VoxelLights;
use super::grid::{disc_bounds, index_discs, index_points, Disc, GridFrame, VoxelIndex};
use super::march::{brute_force, march_ray, Lists};
use super::proxies::{irradiance, place, surface_vpls};
use super::sh::{project_voxel, project_vpl, COEFFS, ORDER};
use super::*;
use crate::bsdf::Material;
use crate::estimators::direct::{Lighting, ProductLevel};
use crate::estimators::many_lights::light_paths::Receiver;
use crate::geometry::{Bounds, Scene};
use crate::lights::envmap::EnvMap;
use crate::lights::vpl::{Vpl, VplKind};
use crate::sampling::rng::SampleRng;

fn rng(seed: u64, i: u64) -> impl Fn(u64) -> f32 {
    move |d| SampleRng::new(seed, i, 0).get(d)
}

fn unit_sphere(u: [f32; 2]) -> Vec3 {
    let z = 1.0 - 2.0 * u[0];
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = std::f32::consts::TAU * u[1];
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

fn bounds(lo: Vec3, hi: Vec3) -> Bounds {
    Bounds { min: lo, max: hi }
}

/// Eq. 1 maps the voxels one to one onto `0..Dx Dy Dz`, and `coords` inverts it.
#[test]
fn eq1_is_a_bijection() {
    for dims in [[1, 1, 1], [3, 5, 7], [6, 6, 6], [1, 9, 2]] {
        let f = GridFrame::new(bounds(Vec3::ZERO, Vec3::ONE), dims).unwrap();
        let mut seen = vec![false; f.voxels() as usize];
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let v = UVec3::new(x, y, z);
                    let k = f.key(v);
                    assert!(!seen[k as usize]);
                    seen[k as usize] = true;
                    assert_eq!(f.coords(k), v);
                }
            }
        }
        assert!(seen.iter().all(|&s| s));
    }
}

fn random_discs(n: usize, seed: u64, scale: f32, radius: f32) -> Vec<Disc> {
    (0..n)
        .map(|i| {
            let r = rng(seed, i as u64);
            Disc {
                centre: Vec3::new(r(0), r(1), r(2)) * scale,
                normal: unit_sphere([r(3), r(4)]),
                radius: radius * scale * (0.5 + r(5)),
            }
        })
        .collect()
}

/// Every point is in exactly one range, its own voxel's; every disc in exactly the voxels
/// its box touches; dense and hashed tables agree, also with T = 7 (collisions).
#[test]
fn ranges_cover_every_item_once() {
    let discs = random_discs(500, 3, 1.0, 0.08);
    let frame = GridFrame::new(bounds(Vec3::ZERO, Vec3::ONE), [5, 4, 6]).unwrap();
    let points: Vec<Vec3> = discs.iter().map(|d| d.centre).collect();
    for slots in [None, Some(7), Some(1), Some(1000)] {
        let idx = index_points(frame, &points, slots).unwrap();
        assert_eq!(idx.is_hashed(), slots.is_some());
        let mut count = vec![0; points.len()];
        for (e, entry) in idx.entries.iter().enumerate() {
            assert!(!idx.range(e).is_empty());
            assert_eq!(idx.entry(entry.voxel), Some(e));
            for &i in idx.range(e) {
                count[i as usize] += 1;
                assert_eq!(frame.voxel_of(points[i as usize]), entry.voxel);
            }
        }
        assert!(count.iter().all(|&c| c == 1));
        let didx = index_discs(frame, &discs, slots).unwrap();
        let mut count = vec![0u32; discs.len()];
        for e in 0..didx.entries.len() {
            for &i in didx.range(e) {
                count[i as usize] += 1;
            }
        }
        for (i, d) in discs.iter().enumerate() {
            let e = d.half_extent();
            let (lo, hi) = (frame.voxel_of(d.centre - e), frame.voxel_of(d.centre + e));
            let want = (hi - lo + UVec3::ONE).element_product();
            assert_eq!(count[i], want, "disc {i}");
            assert!(didx.get(frame.voxel_of(d.centre)).contains(&(i as u32)));
        }
    }
    // Keys that collide in a table of 7 slots are told apart.
    let hashed = index_points(frame, &points, Some(7)).unwrap();
    let dense = index_points(frame, &points, None).unwrap();
    for k in 0..frame.voxels() {
        let v = frame.coords(k);
        assert_eq!(hashed.get(v), dense.get(v), "voxel {v}");
    }
}

fn lambert_vpl(p: Vec3, n: Vec3, flux: Vec3, albedo: [f32; 3]) -> Vpl {
    Vpl {
        position: p,
        origin: p,
        normal: n,
        incident: n,
        material: Material::Lambert { albedo },
        flux,
        kind: VplKind::Surface,
        bounce: 1,
        light: u32::MAX,
    }
}

fn plane_scene(size: f32) -> Scene {
    let mut s = Scene::new();
    let v = [
        [-size, 0.0, -size],
        [size, 0.0, -size],
        [size, 0.0, size],
        [-size, 0.0, size],
    ];
    s.add_indexed(&v, &[[0, 2, 1], [0, 3, 2]], Material::DEFAULT, None)
        .unwrap();
    s
}

/// Empty voxels give empty lists and zero light, never NaN; an empty voxel's SH is zero
/// with a finite centroid; a one-voxel grid holds everything.
#[test]
fn empty_voxels_and_a_one_voxel_grid() {
    let scene = plane_scene(1.0);
    let frame = GridFrame::new(bounds(Vec3::splat(-1.0), Vec3::ONE), [4, 4, 4]).unwrap();
    let vpl = lambert_vpl(Vec3::new(0.9, 0.9, 0.9), -Vec3::Y, Vec3::ONE, [0.5; 3]);
    let set = crate::lights::vpl::VplSet {
        vpls: vec![vpl],
        fingerprint: scene.geometry_fingerprint(),
        ..Default::default()
    };
    let lights = VoxelLights::build(frame, &set, None).unwrap();
    assert_eq!(lights.index.entries.len(), 1);
    let sp = crate::estimators::direct::ShadingPoint {
        origin: Vec3::new(0.0, 0.0, 0.0),
        normal: Vec3::Y,
        wo: Vec3::Y,
        material: Material::DEFAULT,
    };
    let r = Receiver::new(&scene, sp);
    let mut counts = Default::default();
    let lit = frame.key(frame.voxel_of(vpl.position));
    for k in 0..frame.voxels() {
        for range in [0.0, 1.0, f32::INFINITY] {
            let l = lights.voxel_light(k, &r, range, f32::INFINITY, f32::INFINITY, &mut counts);
            assert!(l.is_finite());
            if k != lit {
                assert_eq!(l, glam::DVec3::ZERO);
                assert!(lights.index.get(frame.coords(k)).is_empty());
            } else {
                assert!(l.min_element() > 0.0, "{l}");
            }
        }
    }
    let empty = project_voxel(std::iter::empty());
    assert!(empty.centroid.is_finite() && empty.flux() == glam::DVec3::ZERO);
    assert_eq!(empty.intensity(Vec3::Y), glam::DVec3::ZERO);
    // One voxel: every disc there, and marching equals brute force.
    let discs = random_discs(200, 5, 1.0, 0.05);
    let one = GridFrame::new(
        disc_bounds(bounds(Vec3::ZERO, Vec3::ONE), &discs),
        [1, 1, 1],
    )
    .unwrap();
    let idx = index_discs(one, &discs, None).unwrap();
    assert_eq!(idx.entries.len(), 1);
    assert_eq!(idx.range(0).len(), discs.len());
    for i in 0..2000u64 {
        let r = rng(11, i);
        let o = Vec3::new(r(0), r(1), r(2)) * 1.4 - 0.2;
        let d = unit_sphere([r(3), r(4)]);
        let a = march_ray(&idx, &discs, o, d, 0.0, f32::INFINITY);
        let b = brute_force(&discs, o, d, 0.0, f32::INFINITY);
        assert_eq!(a, b, "ray {i}");
    }
}

/// Same hit, or both miss; the same disc unless another lies at the same distance.
fn same_hit(discs: &[Disc], a: Option<march::DiscHit>, b: Option<march::DiscHit>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(a), Some(b)) => {
            a.disc == b.disc
                || ((a.t - b.t).abs() <= 1e-5 * a.t.abs().max(b.t.abs())
                    && discs[a.disc as usize].radius > 0.0)
        }
        _ => false,
    }
}

/// Marching finds the nearest disc of all on 1e5 random rays: random ones, rays along
/// voxel faces, origins on voxel borders and corners, grazing discs, scenes scaled by
/// 1e-4 and 1e4, with dense and hashed (T = 7) tables.
#[test]
fn marching_equals_brute_force() {
    let mut rays = 0;
    for scale in [1e-4f32, 1.0, 1e4] {
        let discs = random_discs(300, 21, scale, 0.05);
        let frame = GridFrame::new(
            disc_bounds(bounds(Vec3::ZERO, Vec3::splat(scale)), &discs),
            [5, 4, 6],
        )
        .unwrap();
        let dense = index_discs(frame, &discs, None).unwrap();
        let hashed = index_discs(frame, &discs, Some(7)).unwrap();
        let face = |axis: usize, k: u32| frame.origin[axis] + k as f32 * frame.cell[axis];
        for i in 0..11_200u64 {
            let r = rng(scale.to_bits() as u64, i);
            let mut o = Vec3::new(r(0), r(1), r(2)) * scale;
            let mut d = unit_sphere([r(3), r(4)]);
            match i % 4 {
                // Along a face: on a voxel plane, moving within it.
                0 => {
                    let axis = (i / 4 % 3) as usize;
                    o[axis] = face(axis, 1 + (r(5) * 3.0) as u32);
                    d[axis] = 0.0;
                    d = d.normalize();
                }
                // From a voxel corner.
                1 => {
                    o = Vec3::new(face(0, 2), face(1, 1), face(2, 3));
                }
                // Grazing a disc: through a point of it, almost in its plane.
                2 => {
                    let disc = &discs[(r(6) * discs.len() as f32) as usize % discs.len()];
                    let (t, b) = crate::math::orthonormal_basis(disc.normal);
                    let along = (t * (r(7) - 0.5) + b * (r(8) - 0.5)).normalize();
                    let p = disc.centre + along * disc.radius * 0.9 * r(9);
                    d = (along + disc.normal * (r(10) - 0.5) * 1e-3).normalize();
                    o = p - d * scale * 0.5;
                }
                _ => {}
            }
            let want = brute_force(&discs, o, d, 0.0, f32::INFINITY);
            for idx in [&dense, &hashed] {
                let got = march_ray(idx, &discs, o, d, 0.0, f32::INFINITY);
                assert!(
                    same_hit(&discs, got, want),
                    "scale {scale} ray {i} ({o}, {d}): {got:?} vs {want:?}"
                );
            }
            rays += 1;
        }
    }
    assert!(rays >= 33_600);
}

/// The SH of one VPL is its numeric projection, and band 0 keeps its reflected flux.
#[test]
fn sh_of_one_vpl_is_its_projection() {
    let n = Vec3::new(0.3, -0.5, 0.8).normalize();
    let v = lambert_vpl(Vec3::ZERO, n, Vec3::new(2.0, 1.0, 0.5), [0.8, 0.4, 0.2]);
    let c = project_vpl(&v);
    // Midpoint rule over (cos θ, φ): equal areas.
    let (nu, nphi) = (800, 1600);
    let mut num = [glam::DVec3::ZERO; COEFFS];
    let mut y = [0.0f64; COEFFS];
    let cell = 4.0 * std::f64::consts::PI / (nu * nphi) as f64;
    let s = (v.flux * Vec3::new(0.8, 0.4, 0.2)).as_dvec3() / std::f64::consts::PI;
    for i in 0..nu {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / nu as f64;
        let r = (1.0 - z * z).sqrt();
        for j in 0..nphi {
            let phi = std::f64::consts::TAU * (j as f64 + 0.5) / nphi as f64;
            let w = glam::DVec3::new(r * phi.cos(), r * phi.sin(), z);
            let cos = w.dot(n.as_dvec3()).max(0.0);
            crate::sampling::sh::eval(ORDER, w, &mut y);
            for k in 0..COEFFS {
                num[k] += s * (cos * y[k] * cell);
            }
        }
    }
    for k in 0..COEFFS {
        let err = (num[k] - c[k]).abs().max_element();
        assert!(
            err < 2e-4 * s.max_element(),
            "coefficient {k}: {} vs {}",
            num[k],
            c[k]
        );
    }
    let vox = project_voxel([&v]);
    let flux = vox.flux();
    let want = (v.flux * Vec3::new(0.8, 0.4, 0.2)).as_dvec3();
    assert!((flux - want).abs().max_element() < 1e-6 * want.max_element());
    assert_eq!(vox.centroid, v.position);
    // Bands 0-1 of a clamped cosine are positive along the normal and clamped to zero
    // straight behind it.
    let along = vox.intensity(n);
    let back = vox.intensity(-n);
    assert!(along.min_element() > 0.0 && back == glam::DVec3::ZERO);
    // The affine form is the basis's sum, in every direction.
    for i in 0..500 {
        let r = rng(12, i);
        let w = unit_sphere([r(0), r(1)]);
        let (a, b) = (vox.intensity(w), vox.intensity_by_basis(w));
        assert!(
            (a - b).abs().max_element() <= 1e-12 * want.max_element(),
            "{w}: {a} vs {b}"
        );
    }
}

/// A 1 x 1 window is the identity; the output holds the input; no union across a depth
/// or normal jump.
#[test]
fn filter_unions_within_a_surface() {
    let (w, h) = (12usize, 9usize);
    let rows: Vec<Vec<u64>> = (0..w * h)
        .map(|p| {
            let r = rng(4, p as u64);
            let mut k: Vec<u64> = (0..(r(0) * 5.0) as u64)
                .map(|j| (r(1 + j) * 40.0) as u64)
                .collect();
            k.sort_unstable();
            k.dedup();
            k
        })
        .collect();
    let lists = Lists::from_rows(rows.clone());
    // Left half at depth 1 facing +z, right half at depth 2; the top row tilted 60°.
    let surfels: Vec<Surfel> = (0..w * h)
        .map(|p| {
            let (x, y) = (p % w, p / w);
            Surfel {
                depth: if x < w / 2 { 1.0 } else { 2.0 },
                normal: if y == 0 {
                    Vec3::new(0.866, 0.0, 0.5).normalize()
                } else {
                    Vec3::Z
                },
            }
        })
        .collect();
    let same = filter(&lists, &surfels, w, h, 1, 0.1, 0.1).unwrap();
    assert_eq!(same, lists);
    let out = filter(&lists, &surfels, w, h, 5, 0.1, 0.1).unwrap();
    for p in 0..w * h {
        let got = out.get(p);
        assert!(got.windows(2).all(|k| k[0] < k[1]));
        assert!(lists.get(p).iter().all(|k| got.contains(k)), "pixel {p}");
        // Exactly the union over the window's pixels on the same surface.
        let (x, y) = (p % w, p / w);
        let mut want: Vec<u64> = Vec::new();
        for qy in y.saturating_sub(2)..(y + 3).min(h) {
            for qx in x.saturating_sub(2)..(x + 3).min(w) {
                let q = qy * w + qx;
                let side = (qx < w / 2) == (x < w / 2);
                let tilt = (qy == 0) == (y == 0);
                if side && tilt {
                    want.extend(lists.get(q));
                }
            }
        }
        want.sort_unstable();
        want.dedup();
        assert_eq!(got, &want[..], "pixel {p}");
    }
    // Zero tolerances still keep a pixel's own list.
    let strict = filter(&lists, &surfels, w, h, 3, 0.0, 0.0).unwrap();
    for p in 0..w * h {
        assert!(lists.get(p).iter().all(|k| strict.get(p).contains(k)));
    }
}

/// A scene of a few big triangles and 10 000 tiny ones (1e-6 of the mean area): the
/// proxies per class of triangle over 16 seeds are within 4 standard errors of `count ·
/// A_t / A`; placement is the same for every seed's thread count.
#[test]
fn proxies_follow_area() {
    let mut s = Scene::new();
    let mut verts = Vec::new();
    let mut faces = Vec::new();
    // Ten unit right triangles (area 0.5) side by side.
    for i in 0..10 {
        let x = i as f32 * 2.0;
        let b = verts.len() as i64;
        verts.extend([[x, 0.0, 0.0], [x + 1.0, 0.0, 0.0], [x, 1.0, 0.0]]);
        faces.push([b, b + 1, b + 2]);
    }
    // Ten ones of a hundredth of that.
    for i in 0..10 {
        let x = i as f32 * 2.0;
        let b = verts.len() as i64;
        verts.extend([[x, 3.0, 0.0], [x + 0.1, 3.0, 0.0], [x, 3.1, 0.0]]);
        faces.push([b, b + 1, b + 2]);
    }
    let tiny_side = 3e-5f32;
    for i in 0..10_000 {
        let (x, y) = ((i % 100) as f32 * 0.2, 5.0 + (i / 100) as f32 * 0.2);
        let b = verts.len() as i64;
        verts.extend([
            [x, y, 1.0],
            [x + tiny_side, y, 1.0],
            [x, y + tiny_side, 1.0],
        ]);
        faces.push([b, b + 1, b + 2]);
    }
    s.add_indexed(&verts, &faces, Material::DEFAULT, None)
        .unwrap();
    let areas: Vec<f64> = s
        .mesh()
        .triangles
        .iter()
        .map(|t| 0.5 * crate::math::triangle_cross(t).as_dvec3().length())
        .collect();
    let total: f64 = areas.iter().sum();
    let mean = total / areas.len() as f64;
    assert!(
        areas[20] < 2e-6 * mean,
        "tiny: {} of the mean",
        areas[20] / mean
    );
    let count = 2_000_000u32;
    let seeds = 16;
    // Per class: observed proxies, expected, variance (Bernoulli roulette per triangle).
    let classes = [0..10, 10..20, 20..areas.len()];
    let mut got = [0u64; 3];
    let (mut want, mut var) = ([0f64; 3], [0f64; 3]);
    for seed in 0..seeds {
        let p = place(&s, count, seed).unwrap();
        for (c, range) in classes.iter().enumerate() {
            got[c] += p
                .prim
                .iter()
                .filter(|&&t| range.contains(&(t as usize)))
                .count() as u64;
            for t in range.clone() {
                let n = count as f64 * areas[t] / total;
                let f = n - n.floor();
                want[c] += n;
                var[c] += f * (1.0 - f);
            }
        }
        assert!(p.position.iter().all(|v| v.is_finite()));
    }
    for c in 0..3 {
        let se = var[c].sqrt().max(1e-9);
        assert!(
            (got[c] as f64 - want[c]).abs() <= 4.0 * se + 1e-6 * want[c],
            "class {c}: {} vs {} (se {se})",
            got[c],
            want[c]
        );
    }
    assert!(
        want[2] > 1.0,
        "the tiny triangles are owed {} proxies",
        want[2]
    );
}

fn lighting<'a>(scene: &'a Scene, env: &'a EnvMap) -> Lighting<'a> {
    Lighting {
        scene,
        env,
        product_level: ProductLevel::PerMaterial,
    }
}

/// Proxies' irradiance and the whole grid are bit-identical on one and three threads;
/// under a constant sky both sides of an open plane get `E = π L`.
#[test]
fn proxies_are_lit_deterministically() {
    let scene = plane_scene(1.0);
    let env = EnvMap::constant([1.0, 0.5, 0.25], 8).unwrap();
    let light = lighting(&scene, &env);
    let p = place(&scene, 3000, 1).unwrap();
    let one = crate::parallel::with_threads(Some(1), || irradiance(&light, &p, 7, None))
        .unwrap()
        .unwrap();
    let three = crate::parallel::with_threads(Some(3), || irradiance(&light, &p, 7, None))
        .unwrap()
        .unwrap();
    assert_eq!(one, three);
    // The constant sky surrounds the plane: each side gets E = π L.
    let want = glam::DVec3::new(1.0, 0.5, 0.25) * std::f64::consts::PI;
    for side in 0..2 {
        let mean = one.iter().map(|e| e[side].as_dvec3()).sum::<glam::DVec3>() / one.len() as f64;
        assert!(
            (mean - want).abs().max_element() < 0.02 * want.x,
            "{mean} vs {want}"
        );
    }
    let g1 = crate::parallel::with_threads(Some(1), || {
        proxy_grid::ProxyGrid::build(&light, 3000, [3, 2, 3], None, 7, None)
    })
    .unwrap()
    .unwrap();
    let g3 = crate::parallel::with_threads(Some(3), || {
        proxy_grid::ProxyGrid::build(&light, 3000, [3, 2, 3], None, 7, None)
    })
    .unwrap()
    .unwrap();
    assert_eq!(g1.vpls, g3.vpls);
    assert_eq!(g1.disc_index, g3.disc_index);
    assert_eq!(g1.lights.sh, g3.lights.sh);
}

/// `from_surface`'s checks name the argument; a good row makes a bounce-1 surface VPL of
/// flux `E · area`.
#[test]
fn surface_vpls_check_their_rows() {
    let scene = plane_scene(1.0);
    let ok = surface_vpls(
        &scene,
        &[[0.0, 0.0, 0.0]],
        &[[0.0, 2.0, 0.0]],
        &[[1.0, 2.0, 3.0]],
        &[0.5],
        &[0],
        false,
    )
    .unwrap();
    let v = ok.vpls[0];
    assert_eq!((v.kind, v.bounce, v.normal), (VplKind::Surface, 1, Vec3::Y));
    assert_eq!(v.flux, Vec3::new(0.5, 1.0, 1.5));
    let bad = |pos: [f32; 3], n: [f32; 3], e: [f32; 3], a: f32, o: u32| {
        surface_vpls(&scene, &[pos], &[n], &[e], &[a], &[o], false)
            .unwrap_err()
            .to_string()
    };
    assert!(bad([f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0; 3], 1.0, 0).starts_with("positions"));
    assert!(bad([0.0; 3], [0.0; 3], [1.0; 3], 1.0, 0).starts_with("normals"));
    assert!(bad([0.0; 3], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], 1.0, 0).starts_with("irradiance"));
    assert!(bad([0.0; 3], [0.0, 1.0, 0.0], [1.0; 3], 0.0, 0).starts_with("areas"));
    assert!(bad([0.0; 3], [0.0, 1.0, 0.0], [1.0; 3], 1.0, 3).starts_with("objects"));
    let e = surface_vpls(&scene, &[], &[], &[], &[], &[], false).unwrap_err();
    assert!(e.to_string().starts_with("positions"));
    let e = surface_vpls(&scene, &[[0.0; 3]], &[], &[], &[], &[], false).unwrap_err();
    assert!(e.to_string().starts_with("normals"));
}

/// Each parameter out of range is named.
#[test]
fn bad_parameters_are_named() {
    let cam = [256, 192];
    assert!(VfParams {
        indirect: Some([256, 192]),
        marching: Some([64, 48]),
        ..VfParams::DEFAULT
    }
    .validate(cam)
    .is_ok());
    let cases: [(VfParams, &str); 14] = [
        (
            VfParams {
                proxies: 0,
                ..VfParams::DEFAULT
            },
            "proxies",
        ),
        (
            VfParams {
                specular_sigma: 0.0,
                ..VfParams::DEFAULT
            },
            "specular_sigma",
        ),
        (
            VfParams {
                specular_sigma: f32::NAN,
                ..VfParams::DEFAULT
            },
            "specular_sigma",
        ),
        (
            VfParams {
                voxels: [6, 0, 6],
                ..VfParams::DEFAULT
            },
            "voxels",
        ),
        (
            VfParams {
                marching: Some([0, 4]),
                ..VfParams::DEFAULT
            },
            "marching",
        ),
        (
            VfParams {
                marching: Some([300, 4]),
                indirect: Some([256, 192]),
                ..VfParams::DEFAULT
            },
            "marching",
        ),
        (
            VfParams {
                indirect: Some([256, 256]),
                ..VfParams::DEFAULT
            },
            "indirect",
        ),
        (
            VfParams {
                rays_per_pixel: 0,
                indirect: Some([256, 192]),
                ..VfParams::DEFAULT
            },
            "rays_per_pixel",
        ),
        (
            VfParams {
                filter: 4,
                indirect: Some([256, 192]),
                ..VfParams::DEFAULT
            },
            "filter",
        ),
        (
            VfParams {
                depth_tol: f32::NAN,
                indirect: Some([256, 192]),
                ..VfParams::DEFAULT
            },
            "depth_tol",
        ),
        (
            VfParams {
                normal_tol: 1.5,
                indirect: Some([256, 192]),
                ..VfParams::DEFAULT
            },
            "normal_tol",
        ),
        (
            VfParams {
                depth_tol: -0.1,
                indirect: Some([256, 192]),
                ..VfParams::DEFAULT
            },
            "depth_tol",
        ),
        (
            VfParams {
                sh_range: Some(-1.0),
                indirect: Some([256, 192]),
                ..VfParams::DEFAULT
            },
            "sh_range",
        ),
        (
            VfParams {
                sh_range: Some(f32::NAN),
                indirect: Some([256, 192]),
                ..VfParams::DEFAULT
            },
            "sh_range",
        ),
    ];
    for (p, name) in cases {
        let e = p.validate(cam).unwrap_err().to_string();
        assert!(e.starts_with(name), "{name}: {e}");
    }
    assert!(VfParams {
        sh_range: Some(f32::INFINITY),
        indirect: Some([256, 192]),
        ..VfParams::DEFAULT
    }
    .validate(cam)
    .is_ok());
}

/// A voxel index built over nothing answers every voxel with nothing.
#[test]
fn an_empty_index_is_empty() {
    let frame = GridFrame::new(bounds(Vec3::ZERO, Vec3::ONE), [2, 2, 2]).unwrap();
    for slots in [None, Some(7)] {
        let idx = VoxelIndex::build(frame, 0, |_| (UVec3::ZERO, UVec3::ZERO), slots).unwrap();
        assert!(idx.entries.is_empty());
        for k in 0..8 {
            assert!(idx.get(frame.coords(k)).is_empty());
        }
        let d = march_ray(&idx, &[], Vec3::splat(0.5), Vec3::X, 0.0, f32::INFINITY);
        assert_eq!(d, None);
    }
}

/// A diffuse receiver's sum over a voxel of diffuse VPLs in lanes equals the sum of
/// [`Vpl::connect`]'s terms (to f32 rounding), and a glossy receiver takes `connect`'s.
#[test]
fn lanes_equal_connect() {
    let scene = plane_scene(1.0);
    let frame = GridFrame::new(bounds(Vec3::splat(-1.0), Vec3::ONE), [2, 2, 2]).unwrap();
    let vpls: Vec<Vpl> = (0..300)
        .map(|i| {
            let r = rng(9, i);
            let p = Vec3::new(r(0), r(1), r(2)) * 2.0 - 1.0;
            lambert_vpl(
                p,
                unit_sphere([r(3), r(4)]),
                Vec3::new(r(5), r(6), 1.0),
                [0.7, 0.5, 0.3],
            )
        })
        .collect();
    let set = crate::lights::vpl::VplSet {
        vpls: vpls.clone(),
        fingerprint: scene.geometry_fingerprint(),
        ..Default::default()
    };
    let lights = VoxelLights::build(frame, &set, None).unwrap();
    for material in [
        Material::Lambert {
            albedo: [0.6, 0.4, 0.2],
        },
        Material::Phong {
            kd: [0.3; 3],
            ks: [0.5; 3],
            exponent: 20.0,
        },
    ] {
        for t in 0..20u64 {
            let r = rng(10, t);
            let sp = crate::estimators::direct::ShadingPoint {
                origin: Vec3::new(r(0), r(1), r(2)) * 2.0 - 1.0,
                normal: unit_sphere([r(3), r(4)]),
                wo: unit_sphere([r(5), r(6)]),
                material,
            };
            let rec = Receiver::new(&scene, sp);
            let mut counts = Default::default();
            for k in 0..frame.voxels() {
                let got = lights.voxel_light(
                    k,
                    &rec,
                    f32::INFINITY,
                    f32::INFINITY,
                    f32::INFINITY,
                    &mut counts,
                );
                let mut want = glam::DVec3::ZERO;
                for &i in lights.index.get(frame.coords(k)) {
                    if let Some(c) = lights.vpls[i as usize].connect(&rec, None, 0.0) {
                        want += c.value.as_dvec3();
                    }
                }
                let tol = 1e-4 * want.max_element().max(1e-6);
                assert!((got - want).abs().max_element() <= tol, "{got} vs {want}");
            }
        }
    }
}

/// Pools ([`gather::merge`]) keep a voxel's intensity and normals; seen from afar they
/// light a receiver as its VPLs do, to a relative error within `(s / d)²` (`s` a pool's
/// diagonal) that falls with the distance; within the merge range a receiver sums the
/// VPLs themselves (bit for bit).
#[test]
fn pooled_vpls_keep_the_light_from_afar() {
    let scene = plane_scene(1.0);
    let frame = GridFrame::new(bounds(Vec3::ZERO, Vec3::ONE), [1, 1, 1]).unwrap();
    let tilted = Vec3::new(0.3, 1.0, 0.1).normalize();
    let vpls: Vec<Vpl> = (0..500)
        .map(|i| {
            let r = rng(21, i);
            let p = Vec3::new(r(0), 0.5 * r(1), r(2));
            let n = if i % 2 == 0 { Vec3::Y } else { tilted };
            lambert_vpl(p, n, Vec3::new(r(3), r(4), 1.0), [0.7, 0.5, 0.3])
        })
        .collect();
    let refs: Vec<&Vpl> = vpls.iter().collect();
    let (lo, hi) = (Vec3::ZERO, Vec3::new(1.0, 0.5, 1.0));
    let pools = gather::merge(&refs, lo, hi);
    assert!(pools.len() <= 2 * gather::MERGE_CELLS.pow(3) && pools.len() > 8);
    let total: Vec3 = vpls.iter().map(|v| v.diffuse_intensity().unwrap()).sum();
    let pooled: Vec3 = pools.iter().map(|p| p.2).sum();
    assert!((total - pooled).abs().max_element() <= 1e-5 * total.max_element());
    assert!(pools.iter().all(|p| p.1 == Vec3::Y || p.1 == tilted));
    let set = crate::lights::vpl::VplSet {
        vpls,
        fingerprint: scene.geometry_fingerprint(),
        ..Default::default()
    };
    let lights = VoxelLights::build(frame, &set, None).unwrap();
    let s = (hi - lo).length() / gather::MERGE_CELLS as f32;
    let mut last = f64::INFINITY;
    for d in [3.0f32, 6.0, 12.0, 24.0] {
        let sp = crate::estimators::direct::ShadingPoint {
            origin: Vec3::new(0.5, d, 0.4),
            normal: -Vec3::Y,
            wo: -Vec3::Y,
            material: Material::Lambert {
                albedo: [0.6, 0.4, 0.2],
            },
        };
        let rec = Receiver::new(&scene, sp);
        let mut counts = Default::default();
        let key = frame.key(UVec3::ZERO);
        let exact = lights.voxel_light(
            key,
            &rec,
            f32::INFINITY,
            f32::INFINITY,
            f32::INFINITY,
            &mut counts,
        );
        let near = lights.voxel_light(
            key,
            &rec,
            f32::INFINITY,
            2.0 * d,
            f32::INFINITY,
            &mut counts,
        );
        let pooled = lights.voxel_light(key, &rec, f32::INFINITY, 0.0, f32::INFINITY, &mut counts);
        assert_eq!(near, exact);
        let rel = ((pooled - exact).abs() / exact).max_element();
        let bound = ((s / d) as f64).powi(2);
        println!("pooled at d = {d}: relative error {rel:.2e} (bound {bound:.2e})");
        assert!(rel <= bound && rel < last, "d = {d}: {rel} vs {bound}");
        last = rel;
    }
}
