//! The G-buffer: the first hit of one primary ray per pixel, traced once and handed down.
//! Data flows scene → BVH → G-buffer → cache → estimator → image: the cache is built at
//! the G-buffer's points ([`crate::visibility::cache::VisibilityCache::build_from`]), the
//! renderer's anchors are its hits ([`crate::render::render_from`]), and cache AO and the
//! lighting preview read them, so no primary ray is traced twice.

use glam::Vec3;

use super::Camera;
use crate::error::{Error, Result};
use crate::geometry::{Scene, SurfaceHit};

/// First hits of one primary ray per pixel of [`GBuffer::camera`], row-major. Misses have
/// `object = prim = -1`, NaN position and normal, and infinite depth and footprint.
#[derive(Clone, Debug, PartialEq)]
pub struct GBuffer {
    /// The camera whose rays were traced; the buffer has its width and height.
    pub camera: Camera,
    /// Seed of the jitter (the rays pass through points drawn from `(seed, pixel, sample
    /// 0, dimensions 0-1)`); meaningless without [`GBuffer::jittered`].
    pub seed: u64,
    /// Whether the rays pass through jittered points rather than pixel centres.
    pub jittered: bool,
    /// [`Scene::pose_fingerprint`] of the scene traced: the buffer describes that scene in
    /// that pose only.
    pub scene: u64,
    /// Hit points (world units).
    pub position: Vec<[f32; 3]>,
    /// Unit geometric normals flipped to face the camera.
    pub normal: Vec<[f32; 3]>,
    /// Object id of the hit.
    pub object: Vec<i32>,
    /// Triangle index of the hit.
    pub prim: Vec<i32>,
    /// Distance from the eye to the hit (world units, along the ray).
    pub depth: Vec<f32>,
    /// See [`Camera::footprint`] (world units).
    pub footprint: Vec<f32>,
    /// Unit primary-ray directions.
    pub direction: Vec<[f32; 3]>,
}

#[derive(Clone, Copy)]
struct GSample {
    position: Vec3,
    normal: Vec3,
    object: i32,
    prim: i32,
    depth: f32,
    footprint: f32,
    direction: Vec3,
}

impl Default for GSample {
    fn default() -> Self {
        Self {
            position: Vec3::NAN,
            normal: Vec3::NAN,
            object: -1,
            prim: -1,
            depth: f32::INFINITY,
            footprint: f32::INFINITY,
            direction: Vec3::ZERO,
        }
    }
}

impl GBuffer {
    /// Traces one primary ray per pixel. With `jitter`, the ray passes through a position
    /// drawn from `(seed, pixel, sample 0, dimensions 0-1)` ([`super::DIM_PIXEL_JITTER`]);
    /// without, through the centre.
    pub fn render(
        scene: &Scene,
        camera: &Camera,
        seed: u64,
        jitter: bool,
        threads: Option<usize>,
    ) -> Result<Self> {
        camera.check_buffers()?;
        let samples = scene.map_rays(camera.num_pixels(), threads, |i, c| {
            let (o, d) = camera.primary_ray(i, seed, jitter);
            match scene.intersect1(o, d, f32::INFINITY, c) {
                None => GSample {
                    direction: d,
                    ..GSample::default()
                },
                Some(h) => {
                    let n = if h.normal.dot(d) > 0.0 {
                        -h.normal
                    } else {
                        h.normal
                    };
                    GSample {
                        position: h.position,
                        normal: n,
                        object: h.obj as i32,
                        prim: h.prim as i32,
                        depth: h.t,
                        footprint: camera.footprint(d, h.t, n),
                        direction: d,
                    }
                }
            }
        })?;
        Ok(Self {
            camera: *camera,
            seed,
            jittered: jitter,
            scene: scene.pose_fingerprint(),
            position: samples.iter().map(|s| s.position.into()).collect(),
            normal: samples.iter().map(|s| s.normal.into()).collect(),
            object: samples.iter().map(|s| s.object).collect(),
            prim: samples.iter().map(|s| s.prim).collect(),
            depth: samples.iter().map(|s| s.depth).collect(),
            footprint: samples.iter().map(|s| s.footprint).collect(),
            direction: samples.iter().map(|s| s.direction.into()).collect(),
        })
    }

    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.camera.width
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.camera.height
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.object.len()
    }

    /// Whether the buffer has no pixel (never for a buffer from [`GBuffer::render`]).
    pub fn is_empty(&self) -> bool {
        self.object.is_empty()
    }

    /// Number of pixels whose ray hit something.
    pub fn covered_pixels(&self) -> usize {
        self.object.iter().filter(|&&o| o >= 0).count()
    }

    /// Fails, naming `gbuffer`, unless the buffer describes `scene` as it is posed now and,
    /// when given, was traced through `camera`.
    pub fn check(&self, scene: &Scene, camera: Option<&Camera>) -> Result<()> {
        if self.scene != scene.pose_fingerprint() {
            return Err(Error::invalid(
                "gbuffer",
                "was traced in another scene, or another pose of this one; trace it again \
                 with scene.gbuffer(camera)",
            ));
        }
        if camera.is_some_and(|c| *c != self.camera) {
            return Err(Error::invalid(
                "gbuffer",
                "was traced through another camera than the one given",
            ));
        }
        Ok(())
    }

    /// The hit of pixel `i` as [`Scene::intersect1`] found it (`None` for a miss). The
    /// normal is the G-buffer's (facing the camera); barycentrics are not kept (`u = v =
    /// 0`): nothing that shades a hit reads them.
    pub fn surface_hit(&self, i: usize) -> Option<SurfaceHit> {
        let object = self.object[i];
        (object >= 0).then(|| SurfaceHit {
            t: self.depth[i],
            prim: self.prim[i] as u32,
            obj: object as u32,
            u: 0.0,
            v: 0.0,
            position: Vec3::from(self.position[i]),
            normal: Vec3::from(self.normal[i]),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::Material;

    fn cam(w: u32, h: u32) -> Camera {
        Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 45.0, w, h).unwrap()
    }

    #[test]
    fn gbuffer_of_a_facing_quad() {
        let mut s = Scene::new();
        let v = [
            [-10.0, -10.0, 0.0],
            [10.0, -10.0, 0.0],
            [10.0, 10.0, 0.0],
            [-10.0, 10.0, 0.0],
        ];
        // Wound away from the camera: the G-buffer must still report a camera-facing normal.
        s.add_indexed(&v, &[[0, 2, 1], [0, 3, 2]], Material::DEFAULT, None)
            .unwrap();
        let c = cam(8, 6);
        let g = GBuffer::render(&s, &c, 1, true, Some(2)).unwrap();
        let g1 = GBuffer::render(&s, &c, 1, true, Some(1)).unwrap();
        assert_eq!(g, g1);
        for i in 0..48 {
            assert_eq!(g.object[i], 0);
            assert_eq!(g.normal[i], [0.0, 0.0, 1.0]);
            assert!(g.position[i][2].abs() < 1e-6);
            // Face-on at distance ~5: footprint ~ 5 * 2 tan(22.5) / 6, larger off-centre.
            let d = Vec3::from(g.direction[i]);
            let expect = 5.0 / d.z.abs() * (c.pixel_solid_angle(d) / d.z.abs()).sqrt();
            assert!((g.footprint[i] / expect - 1.0).abs() < 1e-4);
        }
        let centre = GBuffer::render(&s, &c, 0, false, None).unwrap();
        assert_ne!(centre.position, g.position);
    }

    #[test]
    fn hits_match_intersect_and_checks_name_the_gbuffer() {
        let mut s = Scene::new();
        let v = [[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
        s.add_indexed(&v, &[[0, 1, 2]], Material::DEFAULT, None)
            .unwrap();
        let c = cam(8, 6);
        let g = GBuffer::render(&s, &c, 0, false, None).unwrap();
        assert!(g.covered_pixels() > 0 && g.covered_pixels() < g.len());
        for i in 0..g.len() {
            let (o, d) = c.primary_ray(i, 0, false);
            let mut counters = Default::default();
            let hit = s.intersect1(o, d, f32::INFINITY, &mut counters);
            match (hit, g.surface_hit(i)) {
                (None, None) => {}
                (Some(h), Some(k)) => {
                    assert_eq!(
                        (h.t, h.prim, h.obj, h.position),
                        (k.t, k.prim, k.obj, k.position)
                    );
                    assert!(h.normal.dot(k.normal).abs() == 1.0);
                }
                other => panic!("pixel {i}: {other:?}"),
            }
        }
        g.check(&s, Some(&c)).unwrap();
        let other_camera = c.with_resolution(4, 3).unwrap();
        assert!(g
            .check(&s, Some(&other_camera))
            .unwrap_err()
            .to_string()
            .starts_with("gbuffer"));
        // A moved object makes another pose; the identity restores the traced one.
        let moved = glam::Affine3A::from_translation(Vec3::X);
        s.set_object_transform(0, moved).unwrap();
        assert!(g
            .check(&s, None)
            .unwrap_err()
            .to_string()
            .starts_with("gbuffer"));
        s.set_object_transform(0, glam::Affine3A::IDENTITY).unwrap();
        g.check(&s, None).unwrap();
        s.add_indexed(&v, &[[0, 1, 2]], Material::DEFAULT, None)
            .unwrap();
        assert!(g.check(&s, None).is_err());
    }
}
