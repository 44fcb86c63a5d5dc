//! The per-sample maths of the many-light renderer: a sample's receivers are the
//! G-buffer's hits, tiles cover the image once, and the pixel sums' estimate.

use super::*;
use crate::camera::GBuffer;
use crate::lights::vpl::TraceParams;

/// Cornell's room at 10 x 7 with a few VPLs.
fn cornell() -> (Scene, EnvMap, Camera, VplSet) {
    let setup = crate::scenes::load("cornell", 1.0, 0).unwrap();
    let mut scene = setup.scene;
    scene.build(Default::default());
    let cam = setup.camera.with_resolution(10, 7).unwrap();
    let p = TraceParams {
        count: 200,
        depth: 1,
        seed: 5,
        importance: None,
        lights: true,
    };
    let vpls = VplSet::trace(&scene, &setup.envmap, None, &p, Some(1)).unwrap();
    (scene, setup.envmap, cam, vpls)
}

/// Every pixel's receiver at sample `s` is the hit of the G-buffer traced with that
/// sample's seed, jittered or not: the samples shaded one by one are those a whole image
/// of first hits gave.
#[test]
fn receivers_are_the_g_buffers_hits() {
    let (scene, env, cam, vpls) = cornell();
    let unoccluded = Unoccluded::default();
    for jitter in [true, false] {
        let params = ManyLightParams {
            jitter,
            seed: 3,
            ..ManyLightParams::DEFAULT
        };
        let g = Gatherer::new(&scene, &env, &cam, &vpls, &params, &unoccluded);
        for s in [0, 5] {
            let buffer = GBuffer::render(&scene, &cam, sample_seed(3, s), jitter, None).unwrap();
            let mut work = GatherWork::default();
            for i in 0..cam.num_pixels() {
                let dir = Vec3::from(buffer.direction[i]);
                match (g.receiver(i, s, &mut work), buffer.surface_hit(i)) {
                    (Receiver::Background(l), None) => assert_eq!(l, env.eval(dir)),
                    (Receiver::Surface { r, .. }, Some(hit)) => {
                        let sp = shading_point_at(&scene, &hit, -dir);
                        assert_eq!(r.sp.origin, sp.origin, "pixel {i}");
                        assert_eq!(r.sp.normal, sp.normal, "pixel {i}");
                        assert_eq!(r.sp.wo, sp.wo, "pixel {i}");
                    }
                    _ => panic!("pixel {i}: hit and miss disagree"),
                }
            }
            assert_eq!(work.primary_rays, cam.num_pixels() as u64);
        }
    }
}

/// Tiles are fixed on the image: each pixel lies in exactly one, clipped at the sides.
#[test]
fn tiles_cover_the_image_once() {
    let (w, h) = (10u32, 7u32);
    let mut seen = vec![0u32; (w * h) as usize];
    let mut tile = Vec::new();
    for i in 0..(w * h) as usize {
        tile_of(i, w, h, &mut tile);
        assert!(tile.contains(&i) && tile.len() <= (TILE * TILE) as usize);
        assert!(tile.windows(2).all(|p| p[0] < p[1]));
        if i == tile[0] {
            tile.iter().for_each(|&p| seen[p] += 1);
        }
    }
    assert!(seen.iter().all(|&n| n == 1));
    tile_of(69, w, h, &mut tile);
    assert_eq!(tile, vec![48, 49, 58, 59, 68, 69]);
}

/// The sums' estimate: the sample variance of the mean from two samples; one sample's
/// draws' variance ([`Gather::Sampled`]) or infinity; none gives 0 and infinity.
#[test]
fn sums_estimate_mean_and_variance() {
    let mut p = VplSums::default();
    assert_eq!(p.estimate(true), ([0.0; 3], [f32::INFINITY; 3]));
    p.add(DVec3::splat(1.0), DVec3::splat(0.25));
    assert_eq!(p.estimate(true), ([1.0; 3], [0.25; 3]));
    assert_eq!(p.estimate(false), ([1.0; 3], [f32::INFINITY; 3]));
    p.add(DVec3::new(3.0, 1.0, 0.0), DVec3::ZERO);
    let (mean, var) = p.estimate(false);
    assert_eq!(mean, [2.0, 1.0, 0.5]);
    // Σ (x - x̄)² / (n (n - 1)): 2 / 2 and 0.5 / 2.
    assert_eq!(var, [1.0, 0.0, 0.25]);
}
