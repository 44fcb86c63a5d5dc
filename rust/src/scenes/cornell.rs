//! `cornell`: the Cornell box, closed on all six sides.
//!
//! **Purpose.** A small room whose visibility is smooth and fully occluded toward the
//! environment: the reference case for area lights (SBF, BLD) and for records that are
//! everywhere "blocked". It follows the classic layout (red wall on the left, green on the
//! right, a short and a tall block turned about 17 degrees in opposite senses, a light
//! panel under the ceiling), but unlike the classic the camera-side wall is **present**:
//! the box is closed and watertight, and the camera stands inside it.
//!
//! **World.** A cube of side 5.5 m: x and z in [-2.75, 2.75], y in [0, 5.5]. Walls face
//! inward. Objects: `floor`, `ceiling`, `back_wall` (z = -2.75), `front_wall` (z = +2.75,
//! behind the camera), `left_wall` (x = -2.75, red), `right_wall` (x = +2.75, green), all
//! Lambertian; `short_block` (1.65 m cube at (0.95, 0, 0.85)) and `tall_block`
//! (1.65 x 3.3 x 1.65 m at (-1.1, 0, -0.9)), closed boxes with outward normals, white;
//! `light`, a 1.3 x 1.05 m quad 5 mm below the ceiling facing down: the scene's one area
//! light, of radiance [`LIGHT_RADIANCE`] (it also reflects like a white Lambertian).
//!
//! **Triangles.** Walls and blocks are cut into cells of at most 0.65 m / sqrt(detail):
//! 1,262 triangles at detail 1 (972 for the room, 108 + 180 for the blocks, 2 for the
//! light).
//!
//! **Camera.** Inside the box, high in the front-right corner at (2.4, 4.9, 2.6), looking
//! down across the room at (-0.6, 0.9, -1); vertical field of view 70 degrees, 256 x 192.
//! The frame shows the floor with both blocks and their contact regions, the red, back and
//! green walls (the classic straight-on view needs the camera outside an open box). Every
//! pixel sees the inside of the box. The seed is unused: the scene has no randomness.
//!
//! **Environment.** A constant white map (radiance 1, 256² texels). The box is closed, so
//! no shading point inside sees it: it matters only if an experiment opens the box
//! (removes a wall), and then it is a furnace-style uniform light with a known answer.
//! The room's own light is the `light` object, which the area-light code makes emit.
//!
//! **Colour bleeding.** The red and green walls are the classic scene's: light they
//! reflect tints the white floor and blocks, redder near the red wall and greener near the
//! green one (`tests/test_scenes.py` measures it on the indirect image).
//!
//! **Variants** ([`build_glossy_floor`], see [`super::load_variant`]): `glossy_floor`
//! makes the floor a normalised Phong BRDF of exponent [`GLOSSY_EXPONENT`] (50, the glossy
//! floor of VF's Cornell box, its figures 1a and 5: `N_s = 50`), `semiglossy_floor` of
//! exponent [`SEMIGLOSSY_EXPONENT`] (10, the low end of its figure 6: `N_s = 10` to 50).
//! The floor's albedo is split between the lobes, `kd + ks` = [`FLOOR_KD`] + [`FLOOR_KS`] =
//! 0.73, the white of the default floor; everything else, triangle for triangle, is the
//! default setup.
//!
//! `dense_blocks` ([`build_dense_blocks`]; BLD's dense objects, issue 66 §5) replaces the
//! blocks by closed bumpy ellipsoids in their places, white as they were: `short_block`
//! of radii 0.8 m, `tall_block` of radii (0.8, 1.6, 0.8) m, each an icosphere of level
//! 6 + round(log4(detail)) (81,920 triangles at detail 1) with bumps of 15% of its radius
//! (seeded by `seed`), its lowest vertex on the floor. 164,814 triangles at detail 1: a box and a
//! hull stand for each in a few triangles, where the exact test walks a deep BVH.

use glam::Vec3;

use super::shapes::{bumpy_ellipsoid, quad, BoxGrid, Face, MAX_ICO_LEVEL};
use super::{camera, check_detail, setup, Setup};
use crate::bsdf::Material;
use crate::error::Result;
use crate::geometry::Mesh;
use crate::lights::EnvMap;

/// Half the side of the room (m).
pub const HALF: f32 = 2.75;
/// Height of the room (m).
pub const HEIGHT: f32 = 5.5;
/// Radiance of the ceiling light, W/(m² sr): the classic scene's warm white.
pub const LIGHT_RADIANCE: [f32; 3] = [17.0, 12.0, 4.0];

/// Phong exponent of the `glossy_floor` variant (VF's `N_s = 50`).
pub const GLOSSY_EXPONENT: f32 = 50.0;
/// Phong exponent of the `semiglossy_floor` variant (VF's `N_s = 10`).
pub const SEMIGLOSSY_EXPONENT: f32 = 10.0;
/// Diffuse albedo of the glossy floors (per channel).
pub const FLOOR_KD: f32 = 0.5;
/// Specular albedo of the glossy floors (per channel): with [`FLOOR_KD`], the default
/// floor's white 0.73.
pub const FLOOR_KS: f32 = 0.23;

/// Builds the setup (see the module docs). `seed` is unused.
pub fn build(detail: f32, _seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    build_with_floor(detail, Material::lambert([0.73, 0.73, 0.73])?)
}

/// The glossy-floor variants (see the module docs): the floor is
/// `Phong(kd = FLOOR_KD, ks = FLOOR_KS, exponent)`, `exponent` in [1, 1e4] (the variants use
/// [`GLOSSY_EXPONENT`] and [`SEMIGLOSSY_EXPONENT`]). `seed` is unused.
pub fn build_glossy_floor(detail: f32, _seed: u64, exponent: f32) -> Result<Setup> {
    check_detail(detail)?;
    build_with_floor(
        detail,
        Material::phong([FLOOR_KD; 3], [FLOOR_KS; 3], exponent)?,
    )
}

/// The `dense_blocks` variant (see the module docs).
pub fn build_dense_blocks(detail: f32, seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    let white = Material::lambert([0.73, 0.73, 0.73])?;
    build_room(detail, white, |name, _, mesh| {
        let (radii, x, z) = match name {
            "short_block" => (Vec3::splat(0.8), 0.95, 0.85),
            _ => (Vec3::new(0.8, 1.6, 0.8), -1.1, -0.9),
        };
        let level = (6.0 + detail.log(4.0).round()).clamp(1.0, MAX_ICO_LEVEL as f32) as u32;
        let centre = Vec3::new(x, radii.y * (1.0 + DENSE_BUMPS), z);
        let stream = (name == "tall_block") as u64;
        let mut t = Vec::new();
        bumpy_ellipsoid(&mut t, centre, radii, level, DENSE_BUMPS, seed ^ stream);
        // Lowered onto the floor: its lowest vertex touches it.
        let low = t
            .iter()
            .flatten()
            .map(|v| v.y)
            .fold(f32::INFINITY, f32::min);
        let t = t.into_iter().map(|tri| tri.map(|v| v - Vec3::Y * low));
        mesh.add_triangles(t, white, Some(name.into()))
    })
}

/// Bump amplitude of the `dense_blocks` variant, a fraction of the radius.
const DENSE_BUMPS: f32 = 0.15;

/// The box with `floor` as the floor's material.
fn build_with_floor(detail: f32, floor: Material) -> Result<Setup> {
    let cell = 0.65 / detail.sqrt();
    let white = Material::lambert([0.73, 0.73, 0.73])?;
    build_room(detail, floor, |name, (center, size, yaw), mesh| {
        let mut t = Vec::new();
        BoxGrid::centered(center, size, yaw.to_radians(), cell).closed(&mut t);
        mesh.add_triangles(t, white, Some(name.into()))
    })
}

/// The room with `floor` as the floor's material, each block (name, its box's centre,
/// size and yaw in degrees) added by `block`.
fn build_room(
    detail: f32,
    floor: Material,
    mut block: impl FnMut(&str, (Vec3, Vec3, f32), &mut Mesh) -> Result<u32>,
) -> Result<Setup> {
    let cell = 0.65 / detail.sqrt();
    let white = Material::lambert([0.73, 0.73, 0.73])?;
    let red = Material::lambert([0.63, 0.065, 0.05])?;
    let green = Material::lambert([0.14, 0.45, 0.091])?;

    let mut mesh = Mesh::new();
    let room = BoxGrid::new(
        Vec3::new(-HALF, 0.0, -HALF),
        Vec3::new(HALF, HEIGHT, HALF),
        cell,
    );
    for (face, name, material) in [
        (Face::NegY, "floor", floor),
        (Face::PosY, "ceiling", white),
        (Face::NegZ, "back_wall", white),
        (Face::PosZ, "front_wall", white),
        (Face::NegX, "left_wall", red),
        (Face::PosX, "right_wall", green),
    ] {
        let mut t = Vec::new();
        room.face(&mut t, face, true);
        mesh.add_triangles(t, material, Some(name.into()))?;
    }

    let side = 1.65;
    let blocks = [
        (
            "short_block",
            Vec3::new(0.95, side * 0.5, 0.85),
            Vec3::splat(side),
            -17f32,
        ),
        (
            "tall_block",
            Vec3::new(-1.1, side, -0.9),
            Vec3::new(side, 2.0 * side, side),
            17f32,
        ),
    ];
    for (name, center, size, yaw) in blocks {
        block(name, (center, size, yaw), &mut mesh)?;
    }

    let (y, hx, hz) = (HEIGHT - 0.005, 0.65, 0.525);
    let mut t = Vec::new();
    // Counter-clockwise seen from below: normal -y.
    quad(
        &mut t,
        Vec3::new(-hx, y, -hz),
        Vec3::new(hx, y, -hz),
        Vec3::new(hx, y, hz),
        Vec3::new(-hx, y, hz),
    );
    mesh.add_triangles(
        t,
        Material::lambert([0.78, 0.78, 0.78])?,
        Some("light".into()),
    )?;

    let cam = camera([2.4, 4.9, 2.6], [-0.6, 0.9, -1.0], 70.0)?;
    let mut s = setup("cornell", mesh, cam, envmap()?);
    let light = s.scene.num_objects() as u32 - 1;
    s.scene.set_emitter(light, LIGHT_RADIANCE)?;
    Ok(s)
}

/// The default environment: constant white (see the module docs).
pub fn envmap() -> Result<EnvMap> {
    EnvMap::constant([1.0; 3], super::ENV_RESOLUTION)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::TraversalCounters;
    use crate::math::triangle_cross;
    use crate::scenes::shapes::sphere_dir;
    use crate::scenes::testing::*;

    #[test]
    fn loads_with_documented_size() {
        let s = build(1.0, 0).unwrap();
        check_basic(&s, "cornell", 1262..=1262);
        assert_eq!(centre_object(&s), "tall_block");
        let b = s.scene.bounds();
        assert_eq!(b.min, Vec3::new(-HALF, 0.0, -HALF));
        assert_eq!(b.max, Vec3::new(HALF, HEIGHT, HALF));
        check_seeds(build, 1.0, false);
        check_scaling(build, 1.0);
        // The light faces down.
        let m = s.scene.mesh();
        let light = m.objects.iter().find(|o| o.name == "light").unwrap();
        let t = &m.triangles[light.first_triangle as usize];
        assert!(triangle_cross(t).normalize().dot(Vec3::NEG_Y) > 0.999);
    }

    #[test]
    fn glossy_floors_change_only_the_floor() {
        let base = build(1.0, 0).unwrap();
        for (variant, exponent) in [
            ("glossy_floor", GLOSSY_EXPONENT),
            ("semiglossy_floor", SEMIGLOSSY_EXPONENT),
        ] {
            let s = crate::scenes::load_variant("cornell", Some(variant), 1.0, 0).unwrap();
            assert_eq!(s.variant.as_deref(), Some(variant));
            check_basic(&s, "cornell", 1262..=1262);
            let (m, b) = (s.scene.mesh(), base.scene.mesh());
            assert_eq!(m.triangles, b.triangles);
            assert_eq!(m.object_ids, b.object_ids);
            assert_eq!(s.camera, base.camera);
            for (o, ob) in m.objects.iter().zip(&b.objects) {
                let mat = o.material;
                if o.name == "floor" {
                    // VF's glossy floors: N_s from 10 to 50.
                    assert!((10.0..=50.0).contains(&exponent));
                    assert_eq!(
                        mat,
                        Material::Phong {
                            kd: [FLOOR_KD; 3],
                            ks: [FLOOR_KS; 3],
                            exponent
                        }
                    );
                    assert_eq!(mat.base_color(), [0.73; 3]);
                } else {
                    assert_eq!(mat, ob.material, "{}", o.name);
                }
            }
            assert_eq!(s.scene.area_lights(), base.scene.area_lights());
        }
        assert!(build_glossy_floor(1.0, 0, 0.5).is_err());
    }

    /// `dense_blocks`: the room and light as the default, the blocks closed dense meshes
    /// standing on the floor inside the room, one seed another shape.
    #[test]
    fn dense_blocks_replace_only_the_blocks() {
        let base = build(1.0, 0).unwrap();
        let s = crate::scenes::load_variant("cornell", Some("dense_blocks"), 1.0, 0).unwrap();
        check_basic(&s, "cornell", 164_814..=164_814);
        let (m, b) = (s.scene.mesh(), base.scene.mesh());
        assert_eq!(m.objects.len(), b.objects.len());
        for (o, ob) in m.objects.iter().zip(&b.objects) {
            assert_eq!((&o.name, o.material), (&ob.name, ob.material));
            let (t, tb) = (
                &m.triangles[o.triangle_range()],
                &b.triangles[ob.triangle_range()],
            );
            if !o.name.ends_with("_block") {
                assert_eq!(t, tb, "{}", o.name);
                continue;
            }
            assert_eq!(t.len(), 81_920, "{}", o.name);
            let bounds = crate::geometry::Bounds::of_triangles(t);
            assert!(bounds.min.y.abs() < 1e-6, "{bounds:?}");
            assert!(bounds.min.cmpgt(Vec3::new(-HALF, -1.0, -HALF)).all());
            assert!(bounds.max.cmplt(Vec3::new(HALF, HEIGHT, HALF)).all());
            // Closed: every directed edge has its reverse in the mesh.
            let key = |v: Vec3| v.to_array().map(f32::to_bits);
            let edges: std::collections::HashSet<_> = t
                .iter()
                .flat_map(|tri| (0..3).map(move |i| (key(tri[i]), key(tri[(i + 1) % 3]))))
                .collect();
            assert!(
                edges.iter().all(|(a, b)| edges.contains(&(*b, *a))),
                "{}",
                o.name
            );
        }
        assert_eq!(s.scene.area_lights(), base.scene.area_lights());
        let other = build_dense_blocks(1.0, 1).unwrap();
        assert_ne!(other.scene.mesh().triangles, m.triangles);
    }

    #[test]
    fn room_is_watertight() {
        // The six walls share one lattice: every edge has exactly one reversed twin. (Rays
        // aimed exactly at a corner of the scene's bounding box can still slip past the
        // BVH's box tests; the geometry itself has no gap.)
        let s = build(1.0, 0).unwrap();
        let m = s.scene.mesh();
        let walls: Vec<_> = m
            .objects
            .iter()
            .filter(|o| o.name.ends_with("wall") || o.name == "floor" || o.name == "ceiling")
            .flat_map(|o| {
                let a = o.first_triangle as usize;
                m.triangles[a..a + o.num_triangles as usize].iter().copied()
            })
            .collect();
        assert_eq!(walls.len(), 972);
        crate::scenes::shapes::tests::assert_closed(&walls);
        for name in ["short_block", "tall_block"] {
            let o = m.objects.iter().find(|o| o.name == name).unwrap();
            let a = o.first_triangle as usize;
            crate::scenes::shapes::tests::assert_closed(
                &m.triangles[a..a + o.num_triangles as usize],
            );
        }
    }

    #[test]
    fn closed_from_inside() {
        let s = build(1.0, 0).unwrap();
        let mut c = TraversalCounters::default();
        let origins = [
            Vec3::new(0.0, HEIGHT * 0.5, 0.0),
            Vec3::new(0.0, 4.2, 0.0),
            Vec3::new(2.0, 1.0, -2.0),
        ];
        for o in origins {
            let mut dirs: Vec<Vec3> = (0..1000u64)
                .map(|i| {
                    let [u, v] = crate::sampling::rng::SampleRng::new(1, i, 0).get2(0);
                    sphere_dir(u, v)
                })
                .collect();
            // Straight at the middles of the room's edges and faces, where walls meet.
            // (Not at its 8 corners: see `room_is_watertight`.)
            for x in [-1.0f32, 0.0, 1.0] {
                for y in [-1.0f32, 0.0, 1.0] {
                    for z in [-1.0f32, 0.0, 1.0] {
                        let p = Vec3::new(x * HALF, (y + 1.0) * HEIGHT * 0.5, z * HALF);
                        if x * y * z == 0.0 && p != o {
                            dirs.push((p - o).normalize());
                        }
                    }
                }
            }
            for d in dirs {
                let h = s.scene.intersect1(o, d, f32::INFINITY, &mut c);
                assert!(h.is_some(), "ray from {o} along {d} escapes");
            }
        }
        // Walls face into the room, blocks out of themselves.
        let h = s
            .scene
            .intersect1(origins[1], Vec3::Y, f32::INFINITY, &mut c)
            .unwrap();
        assert!(h.normal.y < 0.0);
    }
}
