//! `dynamics`: a few simple objects on a large plane.
//!
//! **Purpose.** Little occlusion: most points see most of the sky, and what blocks it
//! are a few large, smooth shapes. The easy case for caching, and a base for experiments
//! that move objects (each object is separate and named, so it can be moved or removed).
//!
//! **World** (metres, ground at y = 0):
//! - `ground`: a 300 x 300 m square centred at the origin (it reaches the camera's
//!   horizon), normal +y; cells of at most 1.35 m / sqrt(detail) over the central
//!   40 x 40 m, growing 1.5 times per step outside it.
//! - `box_large`: a 1.5 m cube centred at (-2, 0.75, -0.5), turned 20 degrees about +y.
//! - `box_flat`: 1 x 0.6 x 2 m (x, y, z) centred at (1.8, 0.3, 1.2), turned -35 degrees.
//! - `pillar`: 0.5 x 2.5 x 0.5 m centred at (0.6, 1.25, -2.5).
//! - `sphere`: an icosphere of radius 0.8 resting on the ground at (0.2, 0.8, 0.6), glossy.
//!
//! All objects are closed with outward normals.
//!
//! **Triangles.** The boxes are cut into cells of 0.25 m / sqrt(detail); the sphere has
//! subdivision level 3 + round(log4(detail)) (1,280 triangles at level 3): 6,768
//! triangles at detail 1 (4,608 for the ground, 880 for the boxes).
//!
//! **Camera.** Eye (5, 4.5, 7) looking down at (0, 0.4, 0), vertical field of view 38
//! degrees, 256 x 192: all four objects and the plane around them; every pixel sees the
//! plane or an object. The seed is unused: the scene has no randomness.
//!
//! **Environment.** [`super::daylight`] with the sun at azimuth 300°, elevation 45° (up
//! and behind the objects as the camera sees them, toward -x -z), so every object casts
//! a shadow toward the camera onto the plane.
//!
//! **Animated variant** ([`build_animated`], `vc.scenes.load("dynamics", animated=True)`):
//! the same setup, in which the `sphere` (object 4) rolls without slipping from its rest
//! position toward (-1, 0, 1) (toward the open ground left of the camera) by up to
//! [`ROLL_DISTANCE`] = 2 m and back, once every [`ROLL_PERIOD`] = 60 frames, with a
//! cosine ease (at most 0.105 m per frame, mid-way). Frame 0 is the static setup. At rest
//! the tip of the sphere's sun shadow lies on the top of `box_flat`; rolling away, the
//! shadow slides off the box onto open ground, and the ground along the sphere's path is
//! uncovered and covered again. The sphere keeps clear of the other objects all along (at least 0.35 m
//! from `box_flat`, 0.5 m from `box_large`).

use glam::Vec3;

use super::shapes::{graded, ground_lattice, icosphere, BoxGrid, MAX_ICO_LEVEL};
use super::{camera, check_detail, setup, Animation, Motion, Setup};
use crate::bsdf::Material;
use crate::error::Result;
use crate::geometry::Mesh;
use crate::lights::EnvMap;

/// Centre and radius of the sphere at rest.
const SPHERE_CENTER: Vec3 = Vec3::new(0.2, 0.8, 0.6);
const SPHERE_RADIUS: f32 = 0.8;

/// Farthest the animated sphere rolls from its rest position, metres.
pub const ROLL_DISTANCE: f32 = 2.0;

/// Frames of one back-and-forth of the animated sphere.
pub const ROLL_PERIOD: u64 = 60;

/// The animated variant (see the module docs): [`build`] plus the sphere's motion.
pub fn build_animated(detail: f32, seed: u64) -> Result<Setup> {
    let mut s = build(detail, seed)?;
    let object = s
        .scene
        .mesh()
        .objects
        .iter()
        .position(|o| o.name == "sphere")
        .expect("dynamics has a sphere") as u32;
    s.animation = Some(Animation {
        object,
        motion: Motion::Roll {
            center: SPHERE_CENTER,
            radius: SPHERE_RADIUS,
            direction: Vec3::new(-1.0, 0.0, 1.0).normalize(),
            distance: ROLL_DISTANCE,
            period: ROLL_PERIOD,
        },
    });
    Ok(s)
}

/// Builds the setup (see the module docs). `seed` is unused.
pub fn build(detail: f32, _seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    let s = detail.sqrt();
    let mut mesh = Mesh::new();

    let mut t = Vec::new();
    let xs = graded(20.0, 1.35 / s, 150.0, 1.5);
    ground_lattice(&mut t, &xs, &xs, 0.0);
    mesh.add_triangles(
        t,
        Material::lambert([0.6, 0.58, 0.52])?,
        Some("ground".into()),
    )?;

    let cell = 0.25 / s;
    let boxes = [
        (
            "box_large",
            Vec3::new(-2.0, 0.75, -0.5),
            Vec3::splat(1.5),
            20f32,
            [0.7, 0.35, 0.15],
        ),
        (
            "box_flat",
            Vec3::new(1.8, 0.3, 1.2),
            Vec3::new(1.0, 0.6, 2.0),
            -35.0,
            [0.2, 0.35, 0.65],
        ),
        (
            "pillar",
            Vec3::new(0.6, 1.25, -2.5),
            Vec3::new(0.5, 2.5, 0.5),
            0.0,
            [0.75, 0.75, 0.72],
        ),
    ];
    for (name, center, size, yaw, albedo) in boxes {
        let mut t = Vec::new();
        BoxGrid::centered(center, size, yaw.to_radians(), cell).closed(&mut t);
        mesh.add_triangles(t, Material::lambert(albedo)?, Some(name.into()))?;
    }

    let level = (3.0 + detail.log(4.0).round()).clamp(1.0, MAX_ICO_LEVEL as f32) as u32;
    let mut t = Vec::new();
    icosphere(&mut t, SPHERE_CENTER, SPHERE_RADIUS, level);
    mesh.add_triangles(
        t,
        Material::phong([0.45, 0.45, 0.5], [0.4; 3], 200.0)?,
        Some("sphere".into()),
    )?;

    let cam = camera([5.0, 4.5, 7.0], [0.0, 0.4, 0.0], 38.0)?;
    Ok(setup("dynamics", mesh, cam, envmap()?))
}

/// The default environment: sky and sun (see the module docs).
pub fn envmap() -> Result<EnvMap> {
    super::daylight(300.0, 45.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::testing::*;

    #[test]
    fn loads_with_documented_size() {
        let s = build(1.0, 0).unwrap();
        check_basic(&s, "dynamics", 6768..=6768);
        let b = s.scene.bounds();
        assert_eq!(b.min, Vec3::new(-150.0, 0.0, -150.0));
        assert_eq!(b.max, Vec3::new(150.0, 2.5, 150.0));
        check_seeds(build, 1.0, false);
        check_scaling(build, 1.0);
    }

    #[test]
    fn little_occlusion() {
        let s = build(1.0, 0).unwrap();
        let c = &s.camera;
        let mut counters = crate::geometry::TraversalCounters::default();
        let (mut sum, mut n) = (0.0, 0);
        for y in 0..6 {
            for x in 0..8 {
                let d = c.direction((x as f32 + 0.5) * 32.0, (y as f32 + 0.5) * 32.0);
                let h = s.scene.intersect1(c.eye, d, f32::INFINITY, &mut counters);
                let h = h.expect("every sampled pixel hits");
                let nrm = if h.normal.dot(d) > 0.0 {
                    -h.normal
                } else {
                    h.normal
                };
                sum += occluded_fraction(&s.scene, h.position, nrm, 64);
                n += 1;
            }
        }
        assert!(sum / (n as f32) < 0.25, "mean occlusion {}", sum / n as f32);
    }

    fn sphere_range(s: &Setup) -> std::ops::Range<usize> {
        s.scene.mesh().objects[s.moving_object().unwrap() as usize].triangle_range()
    }

    /// Smallest distance from the sphere's centre to points spread over the boxes' triangles
    /// (vertices, edge midpoints and centroids; the cells are at most 0.25 m), minus the
    /// radius, over all frames of a period; and the lowest sphere vertex over the period.
    fn clearances(s: &mut Setup) -> ([f32; 3], f32) {
        let anim = s.animation.unwrap();
        let mut gap = [f32::INFINITY; 3];
        let mut lowest = f32::INFINITY;
        for frame in 0..ROLL_PERIOD {
            s.at_frame(frame).unwrap();
            let c = anim.transform(frame).transform_point3(SPHERE_CENTER);
            let mesh = s.scene.mesh();
            for (k, name) in ["box_large", "box_flat", "pillar"].iter().enumerate() {
                let o = mesh.objects.iter().find(|o| &o.name == name).unwrap();
                let first = o.first_triangle as usize;
                for t in &mesh.triangles[first..first + o.num_triangles as usize] {
                    let pts = [
                        t[0],
                        (t[0] + t[1]) * 0.5,
                        (t[1] + t[2]) * 0.5,
                        (t[2] + t[0]) * 0.5,
                        (t[0] + t[1] + t[2]) / 3.0,
                    ];
                    for p in pts {
                        gap[k] = gap[k].min(p.distance(c) - SPHERE_RADIUS);
                    }
                }
            }
            lowest = lowest.min(s.moving_bounds().unwrap().min.y);
        }
        (gap, lowest)
    }

    #[test]
    fn animated_variant_starts_static_moves_only_the_sphere_and_keeps_clear() {
        let still = build(1.0, 0).unwrap();
        let mut a = build_animated(1.0, 0).unwrap();
        assert_eq!(a.name, "dynamics");
        let sphere = a.moving_object().unwrap();
        assert_eq!(a.scene.mesh().objects[sphere as usize].name, "sphere");
        assert_eq!(a.scene.mesh().triangles, still.scene.mesh().triangles);
        assert_eq!(still.moving_object(), None);
        assert_eq!(a.animation.unwrap().period(), ROLL_PERIOD);
        let r = sphere_range(&a);
        for frame in [0, 1, 15, 30, 59, 60, 61, 0] {
            a.at_frame(frame).unwrap();
            assert_eq!(a.frame, frame);
            let (now, rest) = (&a.scene.mesh().triangles, &still.scene.mesh().triangles);
            assert_eq!(now[..r.start], rest[..r.start]);
            assert_eq!(now[r.end..], rest[r.end..]);
            assert_eq!(now[r.clone()] == rest[r.clone()], frame % ROLL_PERIOD == 0);
            assert_eq!(a.scene.bounds(), still.scene.bounds());
        }
        // Half way round, the sphere is `ROLL_DISTANCE` along (-1, 0, 1).
        a.at_frame(30).unwrap();
        let b = a.moving_bounds().unwrap();
        let moved = (b.min + b.max) * 0.5 - SPHERE_CENTER;
        let expect = Vec3::new(-1.0, 0.0, 1.0).normalize() * ROLL_DISTANCE;
        assert!((moved - expect).length() < 0.02, "{moved}");
        // It rolls on the ground and keeps clear of the boxes (documented in the module).
        let (gap, lowest) = clearances(&mut a);
        assert!((0.0..0.01).contains(&lowest), "lowest vertex {lowest}");
        assert!(gap[0] > 0.5 && gap[1] > 0.35 && gap[2] > 1.5, "{gap:?}");
    }

    #[test]
    fn frames_do_not_depend_on_the_frames_before() {
        let mut a = build_animated(0.5, 0).unwrap();
        let mut b = build_animated(0.5, 0).unwrap();
        for f in [17, 3, 59, 42] {
            a.at_frame(f).unwrap();
        }
        b.at_frame(42).unwrap();
        let bits = |s: &Setup| -> Vec<u32> {
            let t = &s.scene.mesh().triangles;
            t.iter()
                .flatten()
                .flat_map(|v| v.to_array().map(f32::to_bits))
                .collect()
        };
        assert_eq!(bits(&a), bits(&b));
        // The same tree too (the rest-pose tree refit): identical hits and node counts.
        let (o, d) = crate::testing::ground_hemisphere_rays(&a.scene, 3000, 2);
        let rays = crate::geometry::RayBatch::new(&o, &d);
        let (ha, hb) = (
            a.scene.intersect(&rays, None),
            b.scene.intersect(&rays, None),
        );
        // Debug strings: misses carry NaN positions, which `==` would call different.
        assert_eq!(format!("{:?}", ha.unwrap()), format!("{:?}", hb.unwrap()));
        let (oa, ob) = (a.scene.occluded(&rays, None), b.scene.occluded(&rays, None));
        assert_eq!(oa.unwrap(), ob.unwrap());
        assert_eq!(a.scene.counters(), b.scene.counters());
        // A scene built before the first frame is refit from the same rest-pose tree.
        let mut c = build_animated(0.5, 0).unwrap();
        c.scene.bvh();
        c.at_frame(42).unwrap();
        let hc = c.scene.intersect(&rays, None).unwrap();
        c.scene.occluded(&rays, None).unwrap();
        assert!(
            hc.obj.contains(&(c.moving_object().unwrap() as i32)),
            "rays see the sphere"
        );
        assert_eq!(c.scene.counters(), b.scene.counters());
    }

    #[test]
    fn static_setups_have_only_frame_zero() {
        let mut s = build(0.25, 0).unwrap();
        s.at_frame(0).unwrap();
        let e = s.at_frame(1).unwrap_err().to_string();
        assert!(e.starts_with("frame"), "{e}");
        assert_eq!(s.frame, 0);
        assert!(s.moving_bounds().is_none());
        let e = super::super::load_animated("garage", 1.0, 0)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("animated") && e.contains("dynamics"), "{e}");
        let e = super::super::load_animated("nope", 1.0, 0)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("name"), "{e}");
        let e = super::super::load_animated("dynamics", f32::NAN, 0)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("detail"), "{e}");
        assert!(super::super::load_animated("dynamics", 0.1, 0)
            .unwrap()
            .animation
            .is_some());
    }

    /// Centroids of the upward-facing triangles of object `name` whose ray toward the sun
    /// first hits the sphere.
    fn in_sphere_shadow(s: &Setup, name: &str) -> usize {
        let sun = crate::lights::procedural::direction(300.0, 45.0);
        let mesh = s.scene.mesh();
        let sphere = s.moving_object().unwrap();
        let o = mesh.objects.iter().find(|o| o.name == name).unwrap();
        let first = o.first_triangle as usize;
        let mut c = crate::geometry::TraversalCounters::default();
        mesh.triangles[first..first + o.num_triangles as usize]
            .iter()
            .filter(|t| crate::math::triangle_cross(t).normalize().y > 0.9)
            .filter(|t| {
                let p = s.scene.offset_point((t[0] + t[1] + t[2]) / 3.0, Vec3::Y);
                let h = s.scene.intersect1(p, sun, f32::INFINITY, &mut c);
                h.is_some_and(|h| h.obj == sphere)
            })
            .count()
    }

    #[test]
    fn the_shadow_slides_off_box_flat_onto_the_ground() {
        let mut a = build_animated(1.0, 0).unwrap();
        a.at_frame(0).unwrap();
        let (box0, ground0) = (
            in_sphere_shadow(&a, "box_flat"),
            in_sphere_shadow(&a, "ground"),
        );
        a.at_frame(ROLL_PERIOD / 2).unwrap();
        let (box1, ground1) = (
            in_sphere_shadow(&a, "box_flat"),
            in_sphere_shadow(&a, "ground"),
        );
        assert!(box0 >= 3 && box1 == 0, "box_flat: {box0} -> {box1}");
        assert!(ground1 > ground0, "ground: {ground0} -> {ground1}");
    }
}
