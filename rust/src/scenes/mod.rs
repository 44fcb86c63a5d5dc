//! Procedural built-in scenes, shared by tests, benches and Python (`vc.scenes.load`).
//!
//! Each setup is a [`Scene`] plus a [`Camera`] (256 x 192 pixels) that frames its
//! interesting part and a default [`EnvMap`] (256² octahedral texels) chosen so that the
//! scene's purpose holds under environment lighting; each module's docs describe its map. Units are metres; the world is right-handed with +y up and the ground,
//! where there is one, at y = 0. Objects are named and carry sensible materials.
//! `detail` in (0, 16] scales triangle counts roughly linearly (1 is the documented size);
//! `seed` drives every random choice through the counter-based generator of
//! [`crate::sampling::rng`], so a seed gives bit-identical geometry on any thread count.
//!
//! | name        | triangles at detail 1 | random | blocked | what it is for | environment map |
//! |-------------|----------------------:|--------|--------:|----------------|-----------------|
//! | `cornell`   | 1,262                 | no     | 0.87 | closed room, area light, smooth visibility | constant white (unseen: the box is closed) |
//! | `garage`    | 11,636                | no     | 0.78 | deep overhang: the sky is mostly occluded | bright windows, mostly hidden by the roof |
//! | `garden`    | 402,332               | yes    | 0.83 | dense grass: near-random visibility | sky and sun |
//! | `dynamics`  | 6,768                 | no     | 0.01 | objects on a plane, little occlusion | sky and sun |
//! | `hairball`  | 1,499,272             | yes    | 0.00 | dense tangle of thin tubes | sky and sun |
//! | `instances` | 210,904               | yes    | 0.43 | 400 randomly rotated solids on a 40 m ground | sky and sun |
//! | `strands`   | 241,800               | yes    | 0.47 | long thin triangles: a stand of reeds | sky and sun |
//! | `room`      | 16,708                | no     | 0.95 | closed room lit through its windows | sky and sun |
//! | `panels`    | 64,010                | yes    | 0.61 | huge triangles spanning the scene over small detail | sky and sun |
//! | `scales`    | 29,152                | yes    | 0.12 | 1 km ground beside centimetre parts | sky and sun |
//! | `blob`      | 330,880               | yes    | 0.31 | one dense closed mesh | sky and sun |
//!
//! "Blocked" is the fraction of shadow rays from the ground (`room`: its floor; `cornell`:
//! the box's floor) in uniform hemisphere directions that hit something
//! ([`crate::testing::ground_hemisphere_rays`], 200,000 rays): the first five scenes are
//! the papers' experiments, the last six the benchmark suite's stress cases (with the real
//! meshes that Python's `vc.scenes.meshes` arranges), and together they span almost open to
//! almost closed.
//!
//! Each module's `//!` gives the exact layout, sizes and camera.
//!
//! **Variants** ([`load_variant`], [`VARIANTS`]): beside the eleven setups above (which
//! stay exactly as they are: their renders are references for other benchmarks), a few
//! scenes have named variants for indirect light. [`INDIRECT_NAMES`] lists the setups meant
//! for indirect light, defaults and variants. The indirect share is the image mean of
//! `method="path", bounces=3, direct=False` over that of `direct=True` at 128 x 96, 256 spp
//! (standard errors at most 0.0022; `python benches/indirect_share.py`): the rest is direct
//! light, including emitters and the map seen by the camera.
//!
//! | scene, variant             | what changes | what it is for | indirect share |
//! |----------------------------|--------------|----------------|---------------:|
//! | `cornell`                  | (default)    | colour bleeding: the red and green walls tint the white floor and blocks | 0.40 |
//! | `cornell`, `glossy_floor`  | floor: Phong, exponent 50 | glossy indirect reflections (VF's figures 1a and 5, `N_s = 50`) | 0.41 |
//! | `cornell`, `semiglossy_floor` | floor: Phong, exponent 10 | the low end of VF's figure 6 (`N_s = 10`) | 0.41 |
//! | `garage`                   | (default)    | windows map, no sun: the walls are lit directly | 0.30 |
//! | `garage`, `sun`            | map: [`daylight`] with a low sun under the roof's edge | a sun patch on the floor inside whose bounce lights the walls and the roof's underside | 0.29 |
//! | `room`, `sunlit`           | map: sun through the back windows; camera turned away from them | a sun-lit interior where indirect light dominates | 0.70 |
//!
//! One variant is not for indirect light: `garage`, `ceiling_lights` (night map, 1,000 small
//! area lights under the roof: many lights, survey ch. 6's importance caching).
//!
//! **Animated setups** ([`load_animated`], [`ANIMATED_NAMES`]): `dynamics` has a variant
//! whose sphere rolls back and forth; [`Setup::at_frame`] moves it (see [`animation`]).
//! Frame 0 of an animated setup is its static setup, triangle for triangle.

pub mod animation;
pub mod blob;
pub mod cornell;
pub mod dynamics;
pub mod garage;
pub mod garden;
pub mod hairball;
pub mod instances;
pub mod panels;
pub mod room;
pub mod scales;
pub mod shapes;
pub mod strands;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::geometry::{Bounds, Mesh, Scene};
use crate::lights::{procedural, EnvMap};
pub use animation::{Animation, Motion};

/// A built-in setup: geometry, a camera that frames it and the environment that lights it.
#[derive(Clone, Debug)]
pub struct Setup {
    /// Name of the built-in scene (one of [`NAMES`]).
    pub name: String,
    /// The geometry.
    pub scene: Scene,
    /// The camera (256 x 192 pixels).
    pub camera: Camera,
    /// The default environment map (256² octahedral texels; see each scene's docs).
    pub envmap: EnvMap,
    /// The moving object and its path, in animated setups ([`load_animated`]).
    pub animation: Option<Animation>,
    /// The frame the scene is at (0 as built).
    pub frame: u64,
    /// The variant of the built-in scene ([`load_variant`]), `None` for the default.
    pub variant: Option<String>,
}

impl Setup {
    /// Moves the scene to `frame` (see [`animation`]): the animated object takes its pose
    /// at `frame` and the BVH is refit. Setups without animation have only frame 0, where
    /// this does nothing; other frames are an error naming `frame`. On error nothing changes.
    pub fn at_frame(&mut self, frame: u64) -> Result<()> {
        match &self.animation {
            None => animation::static_frame(&self.name, frame)?,
            Some(a) => a.apply(&mut self.scene, frame)?,
        }
        self.frame = frame;
        Ok(())
    }

    /// Object id of the moving object, if the setup is animated.
    pub fn moving_object(&self) -> Option<u32> {
        self.animation.map(|a| a.object)
    }

    /// Bounds of the moving object at the current frame, if the setup is animated.
    pub fn moving_bounds(&self) -> Option<Bounds> {
        self.animation.and_then(|a| a.bounds(&self.scene).ok())
    }
}

/// Side of the default environment maps, in octahedral texels.
pub const ENV_RESOLUTION: u32 = 256;

/// Angular diameter of the built-in suns, degrees: twice the real sun's 0.53°, so the disc
/// spans a couple of texels at [`ENV_RESOLUTION`] (about 0.8° each).
pub const SUN_ANGLE_DEG: f32 = 1.0;

/// The built-in daylight: a blue sky (zenith `[0.25, 0.45, 1.0]`, horizon
/// `[0.85, 0.9, 1.0]`) and a warm sun of radiance `4e4 · [1.0, 0.95, 0.85]` and diameter
/// [`SUN_ANGLE_DEG`] at `azimuth_deg` / `elevation_deg` (see
/// [`procedural::direction`]). At 45° elevation the sun's irradiance on open ground is
/// about four times the sky's (luminance ~6.4 against ~1.7).
pub fn daylight(azimuth_deg: f32, elevation_deg: f32) -> Result<EnvMap> {
    procedural::sky(
        procedural::direction(azimuth_deg, elevation_deg),
        [4e4, 3.8e4, 3.4e4],
        SUN_ANGLE_DEG,
        [0.25, 0.45, 1.0],
        [0.85, 0.9, 1.0],
        ENV_RESOLUTION,
    )
}

/// Names of the built-in setups, in a fixed order: the five of the papers' experiments,
/// then the benchmark suite's stress scenes.
pub const NAMES: [&str; 11] = [
    "cornell",
    "garage",
    "garden",
    "dynamics",
    "hairball",
    "instances",
    "strands",
    "room",
    "panels",
    "scales",
    "blob",
];

/// Names of the built-in setups that have an animated variant ([`load_animated`]).
pub const ANIMATED_NAMES: [&str; 1] = ["dynamics"];

/// Named variants of built-in setups, as (scene, variant) pairs, in a fixed order; each
/// scene module's docs describe its variants. The default setups ([`load`]) are unchanged by
/// them.
pub const VARIANTS: [(&str, &str); 6] = [
    ("cornell", "glossy_floor"),
    ("cornell", "semiglossy_floor"),
    ("cornell", "dense_blocks"),
    ("garage", "sun"),
    ("garage", "ceiling_lights"),
    ("room", "sunlit"),
];

/// The setups for indirect light, as (scene, variant) pairs (`None`: the default setup),
/// in a fixed order: see the table in the module docs.
pub const INDIRECT_NAMES: [(&str, Option<&str>); 6] = [
    ("cornell", None),
    ("cornell", Some("glossy_floor")),
    ("cornell", Some("semiglossy_floor")),
    ("garage", None),
    ("garage", Some("sun")),
    ("room", Some("sunlit")),
];

/// Largest accepted `detail`.
pub(crate) const MAX_DETAIL: f32 = 16.0;

/// Camera resolution of every setup.
pub(crate) const WIDTH: u32 = 256;
pub(crate) const HEIGHT: u32 = 192;

/// The names of the built-in setups (see [`NAMES`]).
pub fn names() -> &'static [&'static str] {
    &NAMES
}

/// Builds the setup `name`. `detail` in (0, 16] scales triangle counts (roughly linearly);
/// `seed` drives all randomness. Unknown names and out-of-range details are errors that
/// name the argument.
pub fn load(name: &str, detail: f32, seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    check_load_memory(name, detail)?;
    match name {
        "cornell" => cornell::build(detail, seed),
        "garage" => garage::build(detail, seed),
        "garden" => garden::build(detail, seed),
        "dynamics" => dynamics::build(detail, seed),
        "hairball" => hairball::build(detail, seed),
        "instances" => instances::build(detail, seed),
        "strands" => strands::build(detail, seed),
        "room" => room::build(detail, seed),
        "panels" => panels::build(detail, seed),
        "scales" => scales::build(detail, seed),
        "blob" => blob::build(detail, seed),
        _ => Err(unknown_name(name)),
    }
}

/// The error for a name not in [`NAMES`].
fn unknown_name(name: &str) -> Error {
    Error::invalid(
        "name",
        format!(
            "unknown scene {name:?}; valid names are {}",
            NAMES.join(", ")
        ),
    )
}

/// The variants of the built-in scene `name` (from [`VARIANTS`], possibly none); an
/// unknown name is an error naming `name`.
pub fn variants(name: &str) -> Result<Vec<&'static str>> {
    if !NAMES.contains(&name) {
        return Err(unknown_name(name));
    }
    Ok(VARIANTS
        .iter()
        .filter(|(n, _)| *n == name)
        .map(|(_, v)| *v)
        .collect())
}

/// Builds the setup `name`, or its variant `variant` (one of [`variants`]`(name)`);
/// `variant = None` is [`load`]. Errors name `detail`, then `name` (unknown), then
/// `variant` (not a variant of this scene). The setup's `variant` field records it.
pub fn load_variant(name: &str, variant: Option<&str>, detail: f32, seed: u64) -> Result<Setup> {
    let Some(v) = variant else {
        return load(name, detail, seed);
    };
    check_detail(detail)?;
    let mut s = match (name, v) {
        ("cornell", "glossy_floor") => {
            cornell::build_glossy_floor(detail, seed, cornell::GLOSSY_EXPONENT)?
        }
        ("cornell", "semiglossy_floor") => {
            cornell::build_glossy_floor(detail, seed, cornell::SEMIGLOSSY_EXPONENT)?
        }
        ("cornell", "dense_blocks") => cornell::build_dense_blocks(detail, seed)?,
        ("garage", "sun") => garage::build_sun(detail, seed)?,
        ("garage", "ceiling_lights") => garage::build_ceiling_lights(detail, seed)?,
        ("room", "sunlit") => room::build_sunlit(detail, seed)?,
        _ => {
            let valid = variants(name)?;
            return Err(Error::invalid(
                "variant",
                if valid.is_empty() {
                    format!("scene {name:?} has no variants")
                } else {
                    format!(
                        "scene {name:?} has no variant {v:?}; its variants are {}",
                        valid.join(", ")
                    )
                },
            ));
        }
    };
    s.variant = Some(v.to_string());
    Ok(s)
}

/// Builds the animated variant of setup `name` (one of [`ANIMATED_NAMES`]) at frame 0,
/// where it equals [`load`]'s setup. Errors name `detail`, then `name` (unknown), then
/// `animated` (a known scene without an animated variant).
pub fn load_animated(name: &str, detail: f32, seed: u64) -> Result<Setup> {
    check_detail(detail)?;
    match name {
        "dynamics" => dynamics::build_animated(detail, seed),
        _ if NAMES.contains(&name) => Err(Error::invalid(
            "animated",
            format!(
                "scene {name:?} has no animated variant; animated scenes are {}",
                ANIMATED_NAMES.join(", ")
            ),
        )),
        _ => load(name, detail, seed),
    }
}

/// `detail` must be finite and lie in (0, 16].
/// Triangles of each built-in scene at detail 1 (measured; `scenes.load(name).scene
/// .num_triangles`), for [`check_load_memory`].
const TRIANGLES_AT_DETAIL_1: [(&str, u64); 11] = [
    ("cornell", 1_262),
    ("garage", 11_636),
    ("garden", 402_332),
    ("dynamics", 6_768),
    ("hairball", 1_499_272),
    ("instances", 210_904),
    ("strands", 241_800),
    ("room", 16_708),
    ("panels", 64_010),
    ("scales", 29_152),
    ("blob", 330_880),
];

/// Bytes a triangle takes while a scene is generated, at most: 36 of vertices and 4 of
/// object id, twice over for a growing vector's slack, and the generators' own buffers.
const BYTES_PER_GENERATED_TRIANGLE: usize = 128;

/// Fails with [`Error::OutOfMemory`] (naming `detail`) when the buffers of scene `name` at
/// `detail` could not be allocated: a probe before generating, so that a detail that
/// cannot be met is a `MemoryError` at once, not an abort after minutes. Triangle counts
/// grow at most linearly with detail.
fn check_load_memory(name: &str, detail: f32) -> Result<()> {
    let Some(&(_, triangles)) = TRIANGLES_AT_DETAIL_1.iter().find(|(n, _)| *n == name) else {
        return Ok(());
    };
    let estimate = (triangles as f64 * detail.max(1.0) as f64) as usize;
    crate::alloc::check_memory(
        estimate.saturating_mul(BYTES_PER_GENERATED_TRIANGLE),
        "detail",
    )
}

pub(crate) fn check_detail(detail: f32) -> Result<()> {
    if detail > 0.0 && detail <= MAX_DETAIL {
        Ok(())
    } else {
        Err(Error::invalid(
            "detail",
            format!("must be a number in (0, {MAX_DETAIL}], got {detail}"),
        ))
    }
}

/// A camera with the default resolution and +y up.
pub(crate) fn camera(eye: [f32; 3], target: [f32; 3], fov_deg: f32) -> Result<Camera> {
    Camera::look_at(
        eye.into(),
        target.into(),
        glam::Vec3::Y,
        fov_deg,
        WIDTH,
        HEIGHT,
    )
}

/// Wraps a mesh, a camera and an environment map.
pub(crate) fn setup(name: &str, mesh: Mesh, camera: Camera, envmap: EnvMap) -> Setup {
    Setup {
        name: name.to_string(),
        scene: Scene::from_mesh(mesh),
        camera,
        envmap,
        animation: None,
        frame: 0,
        variant: None,
    }
}

#[cfg(test)]
pub(crate) mod testing {
    //! Checks shared by the scene modules' tests.

    use std::ops::RangeInclusive;

    use glam::Vec3;

    use super::shapes::sphere_dir;
    use super::*;
    use crate::geometry::{SurfaceHit, TraversalCounters};
    use crate::sampling::rng::SampleRng;

    /// Name, size, finite vertices, named non-empty objects, camera, centre-pixel hit.
    pub(crate) fn check_basic(s: &Setup, name: &str, triangles: RangeInclusive<usize>) {
        assert_eq!(s.name, name);
        let n = s.scene.num_triangles();
        assert!(triangles.contains(&n), "{name}: {n} triangles");
        let mesh = s.scene.mesh();
        assert!(mesh.triangles.iter().flatten().all(|v| v.is_finite()));
        for (i, o) in mesh.objects.iter().enumerate() {
            assert_ne!(o.name, format!("object{i}"), "{name}: unnamed object");
            assert!(o.num_triangles > 0, "{name}: empty object {}", o.name);
        }
        let mut names: Vec<_> = mesh.objects.iter().map(|o| &o.name).collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), mesh.objects.len(), "{name}: duplicate names");
        assert_eq!((s.camera.width, s.camera.height), (WIDTH, HEIGHT));
        centre_hit(s);
    }

    /// The hit of the camera's centre ray (panics on a miss).
    pub(crate) fn centre_hit(s: &Setup) -> SurfaceHit {
        let c = &s.camera;
        let d = c.direction(c.width as f32 * 0.5, c.height as f32 * 0.5);
        s.scene
            .intersect1(c.eye, d, f32::INFINITY, &mut TraversalCounters::default())
            .unwrap_or_else(|| panic!("{}: the centre pixel misses", s.name))
    }

    /// Name of the object hit by the centre ray.
    pub(crate) fn centre_object(s: &Setup) -> String {
        let h = centre_hit(s);
        s.scene.mesh().objects[h.obj as usize].name.clone()
    }

    /// Fraction of `count` uniform directions of the hemisphere about `n` that are blocked
    /// from `p` (offset along `n`).
    pub(crate) fn occluded_fraction(scene: &Scene, p: Vec3, n: Vec3, count: u64) -> f32 {
        let o = scene.offset_point(p, n);
        let mut c = TraversalCounters::default();
        let blocked = (0..count)
            .filter(|&i| {
                let [u, v] = SampleRng::new(9, i, 0).get2(0);
                let d = sphere_dir(u, v);
                let d = if d.dot(n) < 0.0 { -d } else { d };
                scene.occluded1(o, d, f32::INFINITY, &mut c)
            })
            .count();
        blocked as f32 / count as f32
    }

    /// Same seed: identical triangles; for `random` scenes another seed changes them.
    pub(crate) fn check_seeds(build: fn(f32, u64) -> Result<Setup>, detail: f32, random: bool) {
        let a = build(detail, 3).unwrap();
        let b = build(detail, 3).unwrap();
        let c = build(detail, 4).unwrap();
        assert_eq!(a.scene.mesh().triangles, b.scene.mesh().triangles);
        assert_eq!(a.scene.mesh().object_ids, b.scene.mesh().object_ids);
        assert_eq!(a.camera, b.camera);
        assert_eq!(
            a.scene.mesh().triangles != c.scene.mesh().triangles,
            random,
            "{}: seed dependence",
            a.name
        );
    }

    /// Fewer triangles at half the detail, roughly in proportion.
    pub(crate) fn check_scaling(build: fn(f32, u64) -> Result<Setup>, detail: f32) {
        let full = build(detail, 0).unwrap().scene.num_triangles() as f32;
        let half = build(detail * 0.5, 0).unwrap().scene.num_triangles() as f32;
        assert!(half < full, "{half} >= {full}");
        assert!(half > 0.25 * full && half < 0.8 * full, "{half} vs {full}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The memory probe knows every scene, and its counts are the scenes' (the small ones
    /// checked here; the rest were measured the same way).
    #[test]
    fn the_load_probe_knows_every_scene() {
        for name in NAMES {
            assert!(
                TRIANGLES_AT_DETAIL_1.iter().any(|(n, _)| *n == name),
                "{name}"
            );
        }
        for (name, triangles) in TRIANGLES_AT_DETAIL_1 {
            if triangles < 20_000 {
                let setup = load(name, 1.0, 0).unwrap();
                assert_eq!(setup.scene.num_triangles() as u64, triangles, "{name}");
            }
        }
        assert!(check_load_memory("hairball", MAX_DETAIL).is_ok());
    }

    #[test]
    fn names_and_errors() {
        assert_eq!(names(), &NAMES);
        let e = load("nope", 1.0, 0).unwrap_err().to_string();
        assert!(e.starts_with("name"), "{e}");
        for n in NAMES {
            assert!(e.contains(n), "{e}");
        }
        for d in [0.0, -1.0, f32::NAN, f32::INFINITY, 16.5, -0.0] {
            let e = load("cornell", d, 0).unwrap_err().to_string();
            assert!(e.starts_with("detail"), "{e}");
            let e = cornell::build(d, 0).unwrap_err().to_string();
            assert!(e.starts_with("detail"), "{e}");
        }
        // The detail is checked first, so its error wins over an unknown name.
        let e = load("nope", f32::NAN, 0).unwrap_err().to_string();
        assert!(e.starts_with("detail"), "{e}");
        assert!(load("cornell", 16.0, 0).is_ok());
        assert!(load("dynamics", 1e-6, 0).is_ok());
    }

    #[test]
    fn variants_load_deterministically_and_name_their_errors() {
        for (name, variant) in VARIANTS {
            assert!(variants(name).unwrap().contains(&variant));
            let a = load_variant(name, Some(variant), 0.25, 3).unwrap();
            let b = load_variant(name, Some(variant), 0.25, 3).unwrap();
            assert_eq!(
                (a.name.as_str(), a.variant.as_deref()),
                (name, Some(variant))
            );
            assert_eq!(a.scene.mesh().triangles, b.scene.mesh().triangles);
            assert_eq!(a.camera, b.camera);
            assert_eq!(a.envmap.texels(), b.envmap.texels());
            assert!(!a.envmap.is_black());
        }
        for (name, variant) in INDIRECT_NAMES {
            assert!(NAMES.contains(&name));
            if let Some(v) = variant {
                assert!(VARIANTS.contains(&(name, v)), "{name} {v}");
            }
        }
        // No variant: the default setup, unchanged.
        let a = load_variant("garage", None, 0.25, 0).unwrap();
        let b = load("garage", 0.25, 0).unwrap();
        assert_eq!(a.variant, None);
        assert_eq!(a.scene.mesh().triangles, b.scene.mesh().triangles);
        assert_eq!(a.envmap.texels(), b.envmap.texels());
        assert_eq!(variants("garden").unwrap(), Vec::<&str>::new());
        assert_eq!(
            variants("cornell").unwrap(),
            ["glossy_floor", "semiglossy_floor", "dense_blocks"]
        );
        let e = |n, v, d| load_variant(n, v, d, 0).unwrap_err().to_string();
        assert!(variants("nope")
            .unwrap_err()
            .to_string()
            .starts_with("name"));
        assert!(e("nope", Some("sun"), 1.0).starts_with("name"));
        assert!(e("nope", Some("sun"), f32::NAN).starts_with("detail"));
        let m = e("cornell", Some("sun"), 1.0);
        assert!(
            m.starts_with("variant") && m.contains("glossy_floor"),
            "{m}"
        );
        assert!(e("garden", Some("sun"), 1.0).contains("no variants"));
    }

    #[test]
    fn parallel_generation_does_not_depend_on_threads() {
        for name in ["garden", "hairball"] {
            let one = crate::parallel::with_threads(Some(1), || load(name, 0.02, 5)).unwrap();
            let two = crate::parallel::with_threads(Some(3), || load(name, 0.02, 5)).unwrap();
            let (one, two) = (one.unwrap(), two.unwrap());
            assert_eq!(one.scene.mesh().triangles, two.scene.mesh().triangles);
        }
    }

    /// Generation times in release builds:
    /// `cargo test --release --lib generation_time -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn generation_time_at_detail_1() {
        for (name, limit) in [("garden", 1.0), ("hairball", 1.5)] {
            let t = std::time::Instant::now();
            let s = load(name, 1.0, 0).unwrap();
            let secs = t.elapsed().as_secs_f64();
            eprintln!(
                "{name}: {} triangles in {secs:.3} s",
                s.scene.num_triangles()
            );
            assert!(secs < limit, "{name}: {secs} s");
        }
    }

    #[test]
    fn daylight_suns_are_where_asked_and_outshine_the_sky() {
        let env = daylight(250.0, 35.0).unwrap();
        let sun = procedural::direction(250.0, 35.0);
        let (d, _) = (0..64)
            .map(|i| {
                env.sample(glam::DVec2::new((i as f64 + 0.5) / 64.0, 0.37))
                    .unwrap()
            })
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        assert!(d.dot(sun) > 0.999, "{d}");
        let p = env.pdf(sun) * 4.0 * std::f64::consts::PI;
        assert!(p > 1e3, "sun texel density {p} x uniform");
    }

    #[test]
    fn every_name_loads() {
        for n in NAMES {
            let d = if matches!(n, "garden" | "hairball" | "strands" | "blob" | "instances") {
                0.01
            } else {
                0.25
            };
            let s = load(n, d, 1).unwrap();
            assert_eq!(s.name, n);
            assert!(s.scene.num_triangles() > 0);
            assert_eq!(s.envmap.resolution(), ENV_RESOLUTION);
            assert!(!s.envmap.is_black(), "{n}");
        }
    }
}
