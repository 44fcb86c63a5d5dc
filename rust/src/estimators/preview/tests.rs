use glam::DMat3;

use super::transfer::{Basis, Transfer, TransferSettings};
use super::*;
use crate::scenes;
use crate::visibility::params::CacheParams;

struct View {
    setup: scenes::Setup,
    camera: Camera,
    cache: VisibilityCache,
}

fn view(name: &str, w: u32, h: u32) -> View {
    let setup = scenes::load(name, 0.3, 0).unwrap();
    let camera = setup.camera.with_resolution(w, h).unwrap();
    let cache = VisibilityCache::new(CacheParams {
        n_startup: 20,
        ..CacheParams::MEDIUM
    })
    .unwrap();
    cache
        .build(&setup.scene, &camera, 0, Some(2), None, &mut |_, _| true)
        .unwrap();
    View {
        setup,
        camera,
        cache,
    }
}

/// `env` with every texel's radiance times `colour`: one chroma over the whole map, where
/// the direct preview's per-region colours are exact.
fn tinted(env: &EnvMap, colour: [f32; 3]) -> EnvMap {
    let texels = env
        .texels()
        .iter()
        .map(|t| {
            let y = 0.2126 * t[0] + 0.7152 * t[1] + 0.0722 * t[2];
            std::array::from_fn(|c| y * colour[c])
        })
        .collect();
    EnvMap::from_octahedral(env.resolution(), texels).unwrap()
}

fn max_relative(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let scale = b
        .iter()
        .flatten()
        .fold(0.0f64, |m, &x| m.max(x.abs() as f64));
    a.iter()
        .flatten()
        .zip(b.iter().flatten())
        .map(|(&x, &y)| (x as f64 - y as f64).abs() / (y.abs() as f64).max(1e-3 * scale))
        .fold(0.0, f64::max)
}

/// The whole transfer with the direct preview's product cells.
const FULL: TransferRequest = TransferRequest {
    basis: BasisChoice::Full,
    settings: TransferSettings {
        product_level: Some(ProductLevel::PerMaterial),
        nearest: false,
    },
    choose_visibility: false,
    ..TransferRequest::DEFAULT
};

/// Kept whole, the transfer gives the direct preview's `J` (same records, same product
/// cells) to 1e-5 relative, for the map and rotated copies of it, with the full Haar basis
/// too (an orthogonal change of basis).
#[test]
fn untruncated_transfer_equals_the_direct_preview() {
    let v = view("garage", 40, 30);
    let preview = LightingPreview::new(&v.setup.scene, &v.camera, Some(2)).unwrap();
    let info = preview
        .prepare(None, &v.cache, None, FULL, Some(2))
        .unwrap();
    assert_eq!(info.basis, Basis::Texels { level: info.level });
    let base = tinted(&v.setup.envmap, [1.0, 0.8, 0.5]);
    for degrees in [0.0f32, 45.0, 135.0] {
        let env = base.rotated(degrees);
        let direct = preview
            .render(&v.cache, &env, ProductLevel::PerMaterial, Some(2))
            .unwrap();
        let cached = preview
            .render_lighting(None, &v.cache, &env, None, Some(2))
            .unwrap();
        let err = max_relative(&cached, &direct);
        assert!(err < 1e-5, "{degrees}°: {err}");
    }
}

/// Every Haar term kept: an orthogonal change of basis, so `J` differs from the whole
/// transfer's only by the rounding of the values to 15 bits, at most `scale / 2 / i16::MAX`
/// each (plus f32 rounding of the transform, far below).
#[test]
fn haar_with_every_term_is_j_within_its_rounding() {
    let v = view("garage", 24, 18);
    let preview = LightingPreview::new(&v.setup.scene, &v.camera, Some(2)).unwrap();
    let points = preview.transfer_points(&v.cache).unwrap();
    let settings = TransferSettings::DEFAULT;
    let materials = points.iter().flatten().map(|p| &p.material);
    let level = Transfer::full_level(&v.cache, materials, &settings).unwrap();
    let full = Transfer::build(
        &points,
        &v.cache,
        settings,
        level,
        Basis::Texels { level },
        None,
    )
    .unwrap();
    let terms = 1 << (2 * level);
    let haar = Transfer::build(
        &points,
        &v.cache,
        settings,
        level,
        Basis::Haar { terms },
        None,
    )
    .unwrap();
    let env = &v.setup.envmap;
    let (lf, lh) = (
        full.light(env, None).unwrap(),
        haar.light(env, None).unwrap(),
    );
    let sums: [f64; 3] =
        std::array::from_fn(|c| lh.values().iter().map(|l| l[c].abs()).sum::<f64>());
    let mut rows = 0;
    for i in 0..points.len() {
        let (a, b) = (full.eval(i, &lf), haar.eval(i, &lh));
        let Some(scale) = haar.haar_scale(i) else {
            assert_eq!(a, [0.0; 3]);
            continue;
        };
        rows += 1;
        for c in 0..3 {
            let bound = scale as f64 * 0.5 / i16::MAX as f64 * sums[c] + 1e-6 * a[c].abs();
            assert!((a[c] - b[c]).abs() <= bound, "pixel {i}: {a:?} vs {b:?}");
        }
    }
    assert!(rows > 100);
}

/// A rotation given to the render equals the map turned beforehand, up to the texel
/// binning of the rotation (mean relative difference ≤ 1%), and a full turn is the
/// identity exactly.
#[test]
fn rotation_matches_a_rotated_map() {
    let v = view("garage", 32, 24);
    let preview = LightingPreview::new(&v.setup.scene, &v.camera, Some(2)).unwrap();
    let env = &v.setup.envmap;
    let r = light::rotation_about_y(45.0).unwrap();
    let turned = preview
        .render_lighting(None, &v.cache, env, Some(&r), Some(2))
        .unwrap();
    let rotated = preview
        .render_lighting(None, &v.cache, &env.rotated(45.0), None, Some(2))
        .unwrap();
    let (mut diff, mut total) = (0.0f64, 0.0f64);
    for (a, b) in turned.iter().flatten().zip(rotated.iter().flatten()) {
        diff += (a - b).abs() as f64;
        total += b.abs() as f64;
    }
    assert!(diff < 0.01 * total, "{}", diff / total);
    let full = light::rotation_about_y(360.0).unwrap();
    assert_eq!(
        preview
            .render_lighting(None, &v.cache, env, Some(&full), Some(2))
            .unwrap(),
        preview
            .render_lighting(None, &v.cache, env, Some(&DMat3::IDENTITY), Some(2))
            .unwrap()
    );
}

/// The transfer is reused while the cache is unchanged and rebuilt when it changes; a
/// cache of another scene is refused; results are the same for any thread count.
#[test]
fn transfer_follows_its_cache() {
    let v = view("garage", 32, 24);
    let preview = LightingPreview::new(&v.setup.scene, &v.camera, Some(1)).unwrap();
    let env = &v.setup.envmap;
    let one = preview
        .render_lighting(None, &v.cache, env, None, Some(1))
        .unwrap();
    let built = preview.transfer_info().unwrap().seconds;
    let two = preview
        .render_lighting(None, &v.cache, env, None, Some(2))
        .unwrap();
    assert_eq!(one, two);
    assert_eq!(preview.transfer_info().unwrap().seconds, built, "reused");
    let before = v.cache.version();
    v.cache
        .insert(
            &v.setup.scene,
            glam::Vec3::new(0.0, 0.01, 0.0),
            glam::Vec3::Y,
        )
        .unwrap();
    assert_ne!(v.cache.version(), before);
    preview
        .render_lighting(None, &v.cache, env, None, Some(2))
        .unwrap();
    let again = preview.transfer_info().unwrap();
    assert_ne!(again.seconds, built, "rebuilt after an insertion");
    let other = view("cornell", 16, 12);
    let e = preview
        .render_lighting(None, &other.cache, env, None, Some(2))
        .unwrap_err();
    assert!(e.to_string().contains("cache"), "{e}");
}

/// Truncated bases stay close to the whole transfer under a smooth map, Haar closer than
/// coarse texels at the same memory, and `"auto"` picks the better one it measured.
#[test]
fn truncated_bases_and_auto() {
    let v = view("garage", 32, 24);
    let preview = LightingPreview::new(&v.setup.scene, &v.camera, Some(2)).unwrap();
    let env = &v.setup.envmap;
    preview
        .prepare(None, &v.cache, Some(env), FULL, Some(2))
        .unwrap();
    let exact = preview
        .render_lighting(None, &v.cache, env, None, Some(2))
        .unwrap();
    let n = (32 * 24) as usize;
    let budget = |per_pixel: usize| 4 * n + per_pixel * n;
    let mut errors = Vec::new();
    for basis in [BasisChoice::Texels, BasisChoice::Haar] {
        let req = TransferRequest {
            basis,
            budget_bytes: budget(512),
            ..TransferRequest::DEFAULT
        };
        let info = preview
            .prepare(None, &v.cache, Some(env), req, Some(2))
            .unwrap();
        assert!(info.bytes <= req.budget_bytes, "{info:?}");
        let img = preview
            .render_lighting(None, &v.cache, env, None, Some(2))
            .unwrap();
        let (mut e, mut p) = (0.0f64, 0.0f64);
        for (a, b) in img.iter().flatten().zip(exact.iter().flatten()) {
            e += ((a - b) as f64).powi(2);
            p += (*b as f64).powi(2);
        }
        errors.push(e / p);
    }
    assert!(errors[1] < errors[0], "{errors:?}");
    assert!(errors[1] < 0.01, "{errors:?}");
    let req = TransferRequest {
        budget_bytes: budget(512),
        ..TransferRequest::DEFAULT
    };
    let info = preview
        .prepare(None, &v.cache, Some(env), req, Some(2))
        .unwrap();
    assert_eq!(info.measured.len(), 3);
    let least = info
        .measured
        .iter()
        .map(|m| m.1)
        .fold(f64::INFINITY, f64::min);
    let kept = info.measured.iter().find(|m| m.0 == info.basis).unwrap();
    assert!(kept.1 <= super::AUTO_SLACK * least, "{info:?}");
    for m in info
        .measured
        .iter()
        .filter(|m| m.1 <= super::AUTO_SLACK * least)
    {
        assert!(
            kept.0.bytes_per_pixel() <= m.0.bytes_per_pixel(),
            "{info:?}"
        );
    }
    let e = preview
        .prepare(
            None,
            &v.cache,
            Some(env),
            TransferRequest {
                budget_bytes: 4 * n,
                ..TransferRequest::DEFAULT
            },
            Some(2),
        )
        .unwrap_err();
    assert!(e.to_string().contains("budget_mb"), "{e}");
}

/// `"auto"` keeps the cheapest basis within the slack of the least error, the lesser
/// error among equally cheap ones, and a much better basis however dear.
#[test]
fn auto_keeps_the_cheapest_basis_within_the_slack() {
    use super::choose::cheapest_within_slack as pick;
    let (haar, sh, texels) = (
        Basis::Haar { terms: 152 },
        Basis::Sh { order: 8 },
        Basis::Texels { level: 3 },
    );
    assert!(sh.bytes_per_pixel() < haar.bytes_per_pixel());
    assert_eq!(pick(&[(haar, 1.0e-4), (sh, 1.2e-4), (texels, 3e-4)]), sh);
    assert_eq!(pick(&[(texels, 1.3e-4), (haar, 1.0e-4), (sh, 1.2e-4)]), sh);
    assert_eq!(
        pick(&[(texels, 1.1e-4), (haar, 1.0e-4), (sh, 1.2e-4)]),
        texels
    );
    assert_eq!(
        pick(&[(haar, 1.36e-4), (sh, 3.65e-3), (texels, 6.4e-3)]),
        haar
    );
    assert_eq!(pick(&[(haar, 1.0e-4), (sh, 1.26e-4)]), haar);
    assert_eq!(pick(&[(haar, 0.0), (texels, 0.0), (sh, 0.0)]), texels);
}

/// A material edit rebuilds the edited object's rows: the result equals a transfer
/// prepared from scratch with the new material.
#[test]
fn material_edit_rebuilds_its_pixels() {
    let v = view("garage", 32, 24);
    let mut preview = LightingPreview::new(&v.setup.scene, &v.camera, Some(2)).unwrap();
    let env = &v.setup.envmap;
    preview
        .render_lighting(None, &v.cache, env, None, Some(2))
        .unwrap();
    let shiny = Material::phong([0.2, 0.3, 0.1], [0.5; 3], 40.0).unwrap();
    let object = preview
        .points
        .iter()
        .flatten()
        .map(|p| p.object)
        .next()
        .unwrap();
    let changed = preview
        .set_material(Some(&v.cache), object, shiny, Some(2))
        .unwrap();
    assert!(changed > 0);
    assert!(preview.transfer_info().is_some(), "kept and patched");
    let patched = preview
        .render_lighting(None, &v.cache, env, None, Some(2))
        .unwrap();
    let fresh = preview.clone();
    *lock(&fresh.transfer) = None;
    let rebuilt = fresh
        .render_lighting(None, &v.cache, env, None, Some(2))
        .unwrap();
    assert_eq!(patched, rebuilt);
    let e = preview
        .set_material(Some(&v.cache), 10_000, shiny, Some(2))
        .unwrap_err();
    assert!(e.to_string().contains("obj"), "{e}");
}

/// Under a sun, a small truncated transfer plus the sun's cells taken exactly stays within
/// a few percent of the whole transfer (whose sun is its cell average of `B~ Ṽ`).
#[test]
fn truncated_transfer_under_a_sun() {
    let v = view("dynamics", 32, 24);
    let preview = LightingPreview::new(&v.setup.scene, &v.camera, Some(2)).unwrap();
    let sun = glam::Vec3::new(0.4, 0.6, -0.5);
    let env = crate::lights::procedural::sky(sun, [4e4; 3], 1.0, [0.25, 0.45, 1.0], [0.85; 3], 256)
        .unwrap();
    preview
        .prepare(
            None,
            &v.cache,
            Some(&env),
            TransferRequest::DEFAULT,
            Some(2),
        )
        .unwrap();
    let whole = preview
        .render_lighting(None, &v.cache, &env, None, Some(2))
        .unwrap();
    let n = 32 * 24;
    for basis in [BasisChoice::Haar, BasisChoice::Texels] {
        let req = TransferRequest {
            basis,
            budget_bytes: n * (4 + 64 + 300),
            ..TransferRequest::DEFAULT
        };
        preview
            .prepare(None, &v.cache, Some(&env), req, Some(2))
            .unwrap();
        let img = preview
            .render_lighting(None, &v.cache, &env, None, Some(2))
            .unwrap();
        let (mut e, mut p) = (0.0f64, 0.0f64);
        for (a, b) in img.iter().flatten().zip(whole.iter().flatten()) {
            e += ((a - b) as f64).powi(2);
            p += (*b as f64).powi(2);
        }
        assert!(e / p < 0.01, "{basis:?}: {}", e / p);
    }
}

/// Under a constant map only `T`'s band-0 coefficient counts, and SH keeps it exactly (the
/// cell averages integrate to `∫ T Y_0`): the SH transfer equals the whole one but for the
/// map's higher coefficients, which the texel-centre quadrature leaves at up to 3.4e-5 of
/// band 0 at 256² (`sampling::sh` tests): with T's 63 others below band 0 that is at most
/// 2e-3, and 5e-4 holds with the map turned any way (SH rotation matrices).
#[test]
fn sh_transfer_is_exact_under_a_constant_map() {
    let v = view("garage", 24, 18);
    let preview = LightingPreview::new(&v.setup.scene, &v.camera, Some(2)).unwrap();
    let env = EnvMap::constant([0.4, 0.7, 1.3], 256).unwrap();
    let whole = preview
        .render_lighting(None, &v.cache, &env, None, Some(2))
        .unwrap();
    let columns = {
        let state = v.cache.read();
        bright::RecordColumns::bytes_for(state.store().len(), state.store().m())
    };
    let req = TransferRequest {
        basis: BasisChoice::Sh,
        budget_bytes: 24 * 18 * (4 + 64 + 256) + columns,
        ..TransferRequest::DEFAULT
    };
    let info = preview
        .prepare(None, &v.cache, Some(&env), req, Some(2))
        .unwrap();
    assert_eq!(info.basis, Basis::Sh { order: 8 });
    let r = DMat3::from_axis_angle(glam::DVec3::new(0.3, 1.0, 0.2).normalize(), 0.7);
    for rotation in [None, Some(&r)] {
        let sh = preview
            .render_lighting(None, &v.cache, &env, rotation, Some(2))
            .unwrap();
        let err = max_relative(&sh, &whole);
        assert!(err < 5e-4, "{err}");
    }
}

/// With the scene, the request picks the form of `Ṽ` whose `J` lies closer to the exact
/// visibility's at traced pixels, and says so; without it (or when told) it keeps the blend.
#[test]
fn visibility_form_is_chosen_by_measurement() {
    let v = view("hairball", 32, 24);
    let preview = LightingPreview::new(&v.setup.scene, &v.camera, Some(2)).unwrap();
    let env = &v.setup.envmap;
    let info = preview
        .prepare(
            Some(&v.setup.scene),
            &v.cache,
            Some(env),
            TransferRequest::DEFAULT,
            Some(2),
        )
        .unwrap();
    let m = info.visibility_measured.expect("measured");
    assert!(m.blend.is_finite() && m.nearest.is_finite() && m.blend >= 0.0 && m.nearest >= 0.0);
    assert!(m.standard_error.is_finite() && m.standard_error >= 0.0);
    assert_eq!(info.nearest, m.nearest < m.blend);
    let info = preview
        .prepare(None, &v.cache, Some(env), TransferRequest::DEFAULT, Some(2))
        .unwrap();
    assert!(info.visibility_measured.is_none() && !info.nearest);
}

/// Each lighting's bright cells take shadow rays from the pixels whose records disagree
/// on them: with a budget that takes them all, recomputed here pixel by pixel, those
/// pixels (and only those, above the cell's horizon) trace one ray per aim, which decide
/// their visibility; the others keep the records' agreed answer; the render equals the
/// transfer plus the bright cells so formed, the same for any thread count. A budget
/// that takes some traces at most its rays and judges the form of the rest on its
/// sample; a budget of 0, or no scene, traces none and keeps the form prepared.
#[test]
fn bright_cells_trace_rays_where_records_disagree() {
    let v = view("dynamics", 32, 24);
    let scene = &v.setup.scene;
    let preview = LightingPreview::new(scene, &v.camera, Some(2)).unwrap();
    let sun = glam::Vec3::new(0.4, 0.6, -0.5);
    let env = crate::lights::procedural::sky(sun, [4e4; 3], 1.0, [0.25, 0.45, 1.0], [0.85; 3], 256)
        .unwrap();
    let request = TransferRequest {
        basis: BasisChoice::Haar,
        budget_bytes: 32 * 24 * (4 + 64 + 300 + 8),
        edge_rays: 100.0,
        ..TransferRequest::DEFAULT
    };
    preview
        .prepare(Some(scene), &v.cache, Some(&env), request, Some(2))
        .unwrap();
    let prepared = lock(&preview.transfer).clone().unwrap();
    // The image turned by `r` on 1 thread, after checking it is the one of 2 threads.
    let on_both_thread_counts = |r: &glam::DMat3| {
        let [one, two] = [1, 2].map(|threads| {
            preview
                .render_lighting(Some(scene), &v.cache, &env, Some(r), Some(threads))
                .unwrap()
        });
        assert_eq!(one, two, "threads");
        one
    };
    let (mut traced_pixels, mut agreed_pixels, mut all_rays) = (0, 0, 0);
    for turn in [0.0, 135.0] {
        let r = light::rotation_about_y(turn).unwrap();
        let img = on_both_thread_counts(&r);
        let choice = preview.last_bright().expect("a sun");
        let transfer = &prepared.transfer;
        let (cells, mut bright) = split_light(&env, transfer.level(), Some(&r), true).unwrap();
        bright.aim(&env, transfer.level(), Some(&r));
        let light = transfer.light_for(&env, Some(&r), cells, &bright).unwrap();
        let state = v.cache.read();
        let masks = bright.record_masks(&state, transfer.level());
        let records = prepared.records.as_ref().unwrap();
        let (mut rays, mut pixels) = (0u64, 0usize);
        for (i, p) in preview.points.iter().enumerate() {
            let Ok(p) = p else { continue };
            if !transfer.has_row(i) {
                continue;
            }
            let origin = scene.offset_point(p.position, p.normal);
            let mut traced = false;
            let want_bright = bright.light(&p.shading(), |s| {
                if let Some(v) = records.agreed(i, s, &masks) {
                    agreed_pixels += 1;
                    return v;
                }
                traced = true;
                let mut open = 0.0;
                for &(d, share) in &bright.aims[s] {
                    rays += 1;
                    let mut c = crate::geometry::TraversalCounters::default();
                    if !scene.occluded1(origin, d, f32::INFINITY, &mut c) {
                        open += f64::from(share) / bright::AIMS as f64;
                    }
                }
                open
            });
            pixels += usize::from(traced);
            traced_pixels += usize::from(traced);
            let smooth = transfer.eval(i, &light);
            let ratios = p.material.channel_ratios();
            for c in 0..3 {
                let r = ratios[c] as f64;
                let want = p.emitted[c] + (r * (smooth[c] + want_bright[c])) as f32;
                assert!(
                    (img[i][c] - want).abs() <= 1e-5 * want.abs().max(1e-3),
                    "pixel {i}: {} against {want}",
                    img[i][c]
                );
            }
        }
        assert_eq!(choice.rays, Some(rays));
        assert_eq!(choice.pixels, pixels);
        assert_eq!(choice.cells, bright.cells.len());
        assert_eq!(choice.nearest, prepared.settings.nearest);
        assert!(choice.errors.is_none());
        all_rays = all_rays.max(rays);
    }
    assert!(
        traced_pixels > 0 && agreed_pixels > 0,
        "{traced_pixels} {agreed_pixels}"
    );
    preview
        .render_lighting(None, &v.cache, &env, None, Some(2))
        .unwrap();
    let fixed = preview.last_bright().unwrap();
    assert!(fixed.rays.is_none() && fixed.pixels == 0);
    assert_eq!(fixed.nearest, prepared.settings.nearest);
    // A budget of a quarter of the rays wanted.
    let budget = all_rays as usize / 4;
    let tight = TransferRequest {
        edge_rays: budget as f64 / (32.0 * 24.0),
        ..request
    };
    preview
        .prepare(Some(scene), &v.cache, Some(&env), tight, Some(2))
        .unwrap();
    let r = light::rotation_about_y(135.0).unwrap();
    on_both_thread_counts(&r);
    let choice = preview.last_bright().unwrap();
    let errors = choice.errors.expect("judged");
    assert!(choice.rays.unwrap() as usize <= budget && errors.pixels >= 1);
    assert_eq!(choice.nearest, errors.prefers_nearest());
    let none = TransferRequest {
        edge_rays: 0.0,
        ..request
    };
    preview
        .prepare(Some(scene), &v.cache, Some(&env), none, Some(2))
        .unwrap();
    preview
        .render_lighting(Some(scene), &v.cache, &env, Some(&r), Some(2))
        .unwrap();
    let choice = preview.last_bright().unwrap();
    assert!(choice.rays.is_none() && choice.errors.is_none());
}

/// The records' masks read by direction equal those read record by record, for cells of
/// every level from the records' own up and any number of cells.
#[test]
fn columns_give_the_records_masks() {
    let v = view("dynamics", 48, 36);
    let state = v.cache.read();
    let columns = bright::RecordColumns::of(&state).unwrap();
    let (m, records) = (state.store().m(), state.store().len());
    assert!(records > 64 && records % 64 != 0, "{records} records");
    assert_eq!(
        columns.memory_bytes(),
        bright::RecordColumns::bytes_for(records, m)
    );
    for level in [m, m + 1, 6] {
        let all: Vec<u32> = (0..1u32 << (2 * level)).step_by(5).collect();
        for (k, cells) in all.chunks(bright::MAX_BRIGHT).enumerate() {
            let cells = &cells[..1 + k % cells.len()];
            let bright = bright::BrightCells {
                cells: cells.to_vec(),
                ..Default::default()
            };
            let masks = columns.masks(&bright, level);
            assert_eq!(masks, bright.record_masks(&state, level), "level {level}");
        }
    }
}

/// Every phase of `prepare` polls the current stop: run alone under a set stop, each fails
/// with `Interrupted`, as do `prepare` (keeping no transfer) and `from_gbuffer`; outside the
/// stop's scope the same calls succeed.
#[test]
fn a_set_stop_interrupts_every_phase_of_prepare() {
    let v = view("garage", 40, 30);
    let (scene, env) = (&v.setup.scene, &v.setup.envmap);
    let g = GBuffer::render(scene, &v.camera, 0, false, Some(2)).unwrap();
    let preview = LightingPreview::from_gbuffer(scene, &g).unwrap();
    let points = preview.transfer_points(&v.cache).unwrap();
    let settings = TransferSettings::DEFAULT;
    let level = preview.full_level(&v.cache, &settings).unwrap();
    let (cells, bright) = split_light(env, level, None, true).unwrap();
    let columns = bright::RecordColumns::of(&v.cache.read()).unwrap();
    let masks = columns.masks(&bright, level);
    let basis = Basis::Haar { terms: 16 };
    let params = v.cache.params();
    let phases = || -> Vec<(&str, Result<()>)> {
        vec![
            (
                "transfer_points",
                preview.transfer_points(&v.cache).map(drop),
            ),
            (
                "full_level",
                preview.full_level(&v.cache, &settings).map(drop),
            ),
            (
                "columns",
                bright::RecordColumns::of(&v.cache.read()).map(drop),
            ),
            (
                "records",
                bright::PixelRecords::gather(&points, &v.cache.read(), params).map(drop),
            ),
            ("split_light", split_light(env, level, None, true).map(drop)),
            (
                "measure_visibility",
                choose::measure_visibility(scene, &points, &v.cache, &settings, level, {
                    (&cells, &bright)
                })
                .map(drop),
            ),
            (
                "measure",
                choose::measure(&points, &v.cache, &settings, level, &[basis], env, {
                    (&cells, &bright, &masks)
                })
                .map(drop),
            ),
            (
                "build",
                Transfer::build(&points, &v.cache, settings, level, basis, None).map(drop),
            ),
            (
                "prepare",
                preview
                    .prepare(
                        Some(scene),
                        &v.cache,
                        None,
                        TransferRequest::DEFAULT,
                        Some(2),
                    )
                    .map(drop),
            ),
            (
                "from_gbuffer",
                LightingPreview::from_gbuffer(scene, &g).map(drop),
            ),
        ]
    };
    let stop = Stop::new();
    stop.set();
    for (phase, r) in stop.scope(phases) {
        assert!(
            matches!(r, Err(crate::error::Error::Interrupted { .. })),
            "{phase}: {r:?}"
        );
    }
    assert!(
        preview.transfer_info().is_none(),
        "a stopped prepare keeps nothing"
    );
    for (phase, r) in phases() {
        assert!(r.is_ok(), "{phase}: {r:?}");
    }
    assert!(preview.transfer_info().is_some());
}
