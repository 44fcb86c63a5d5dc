"""``relight``: decoupled visibility with an error bound (SBF, Fig. 1-2) after lighting
edits, on fixed pixel centres.

Cases: ``garage`` with its map rotated by 45 degrees and swapped for another sky; the Cornell
box with a white area light under its ceiling whose texture turns into a red and green
checker after visibility converged (SBF's pattern switch, Fig. 1); ``meshes`` with its map rotated
(when the shared meshes are found). Visibility converges under the original lighting
(``converge_visibility``, 256 V-samples; ``visibility="pixels"``, and ``"cache"`` with a
"medium" cache; where the scene has area lights, also ``"cache_lights"``: the same with a
second "medium" cache whose records see the lights, ``light_cache``), then the edit is
applied and:

- **the bound**: per pixel, the estimated absolute error of ``<LB><V>`` (``lb_spp`` 16/64/256)
  against the actual error of ``<LB><V>`` (``lb_spp`` 1024; lights without ``<V>`` by
  256-spp ``<LBV>``) from a 1024-spp product reference under the edit, with three
  standard errors of both for noise: the share of covered pixels where the bound holds
  (target: >= 95% at lb_spp 64);
- **equal time**: the blend at thresholds 0.05/0.1/0.25 (``lb_spp`` 8, ``lbv_spp`` 8: SBF's
  regime, its Fig. 1 compares 8 V-samples with 9) against product sampling (the classical
  ``<LBV>``, with its defaults: adaptive counts and light draws per sample, so its spp is
  the mean over pixels) given the blend's seconds; and at 0.25 both given
  ``EQUAL_TIME_SECONDS``, the blend adding passes of ``LBV``-samples (adaptive counts, the
  default; its ``lbv_spp`` is the mean over pixels), and SBF's own classical estimator
  (the relighter's ``<LBV>`` alone, threshold 0 and ``reuse=False``, of the same density,
  reading no ``<V>``) given the same seconds: relMSE on RGB against the reference,
  and the share of pixels whose relative error exceeds the threshold (target at 0.25:
  relMSE <= 0.4x classical, <= 2% of pixels over), both as ``|x - ref| / ref`` and with
  relMSE's denominator ``sqrt(ref^2 + 1e-2)`` (beside product sampling's share): near-black
  pixels, whose reference is itself noisy (22% relative standard error on garage's dark
  ceiling at 4096 spp), dominate the first;
- **overhead** (SBF's 16% and 5%): the first frame after the edit (``lb_spp`` 64 and
  ``lbv_spp`` 8: ``Var(LB/p)`` is estimated) over a product render of 8 spp, and the later
  frames (the budgeted passes of ``LBV``-samples) per sample over a product render of as many
  samples per sample; and the bytes per pixel and light of the stored visibility;
- **a camera move** (``visibility="cache"``; on the Cornell box with ``light_cache``): the same
  bound check at a moved view, no V rays.

Seconds are wall-clock on a shared machine: the equal-time figures move by tens of percent
from run to run. ``--quick``: 64x48 and the bound at lb_spp 64 only (a minute or two);
full: 160x120.
"""

from __future__ import annotations

from typing import Any

import numpy as np

import viscache_rs as vc

from ._context import ExperimentContext

DESCRIPTION = __doc__

V_SPP = 256
#: Samples of the references: quick, full.
REFERENCE_SPP = {True: 1024, False: 4096}
#: Seconds of each equal-time render: quick, full.
EQUAL_TIME_SECONDS = {True: 0.1, False: 0.5}
#: Image sizes of --quick and of the full mode.
SIZES = {True: (64, 48), False: (160, 120)}
THRESHOLDS = (0.05, 0.1, 0.25)
#: LB-samples of the equal-time renders (the 8 LBV-samples are LB-samples too).
EQUAL_TIME_LB_SPP = 8
NOISE_SIGMAS = 3.0
#: Offsets of the eye for the check after a camera move (the view keeps its direction).
CAMERA_MOVES = {"garage_rot45": (0.5, 0.1, 0.0), "cornell_red_green": (-0.4, -0.3, -0.3)}
#: relMSE's floor, for the share of pixels over the threshold measured with its denominator.
RELMSE_FLOOR = vc.metrics.DENOMINATOR_FLOOR


def _cases(quick: bool):
    """(name, setup, edit) where edit(setup) applies the lighting change and returns the
    map to render with."""
    garage = vc.scenes.load("garage")
    sky = vc.EnvMap.sky((0.6, 0.5, -0.62), 3e4, 1.0, (0.15, 0.3, 0.8), (0.6, 0.7, 0.9), 256)
    yield "garage_rot45", garage, lambda s: s.envmap.rotated(45)
    yield "garage_sky", garage, lambda s: sky
    box = vc.scenes.load("cornell")
    quad = np.array([[-0.4, 1.95, -0.2], [0.4, 1.95, -0.2], [0.4, 1.95, 0.2],
                     [-0.4, 1.95, 0.2]])
    light = box.scene.add_area_light(quad, (5, 5, 5))
    # SBF Fig. 1: after visibility converged, the light's texture turns from white to a
    # red and green pattern (8 x 4 checker), sampled by area as before.
    checker = np.indices((4, 8)).sum(axis=0) % 2
    pattern = np.where(checker[..., None] == 0, (1.6, 0.1, 0.1), (0.1, 1.6, 0.1))
    pattern = pattern.astype(np.float32)

    def switch(s, light=light, pattern=pattern):
        s.scene.set_emission_texture(light, pattern)
        return s.envmap

    yield "cornell_red_green", box, switch
    if vc.scenes.models_dir(required=False) is not None:
        yield "meshes_rot45", vc.scenes.load("meshes"), lambda s: s.envmap.rotated(45)


def _decoupled(rl, env, seed, camera=None):
    """``<LB><V>`` with 1024 LB-samples (``t`` within 1e-9 of 1: eq. 11 alone) where a light
    has ``<V>``, and 256-spp ``<LBV>`` where it has none (area lights in cache mode)."""
    return rl.render(envmap=env, lb_spp=1024, lbv_spp=256, threshold=1e12, epsilon=1e-9,
                     seed=seed, camera=camera, least_error=False, reuse=False)


def _bound_holds(est, actual_image, reference, n_sigma=NOISE_SIGMAS) -> tuple[float, int]:
    """Share of covered pixels where |<LB><V> - L| <= the estimated bound (+ noise)."""
    covered = np.isfinite(est.t).any(axis=-1)
    err = np.abs(actual_image.image.astype(np.float64) - reference.image)
    noise = n_sigma * np.sqrt(actual_image.variance.astype(np.float64) + reference.variance)
    holds = np.all(err <= est.error_bound + noise, axis=-1)
    return float(holds[covered].mean()), int(covered.sum())


def _over_threshold(image, reference, threshold, floor: float = 0.0) -> float:
    """Share of lit pixels whose relative error (worst channel) exceeds ``threshold``:
    ``|x - ref| / ref``, or with ``floor`` ``|x - ref| / sqrt(ref^2 + floor)`` (relMSE's
    denominator, ``vc.metrics``: a near-black pixel's error is judged against the floor)."""
    ref = reference.image.astype(np.float64)
    lit = np.all(ref > 1e-6, axis=-1)
    scale = np.sqrt(ref * ref + floor) if floor > 0 else np.maximum(ref, 1e-6)
    rel = np.max(np.abs(image - ref) / scale, axis=-1)
    return float((rel[lit] > threshold).mean())


def run(ctx: ExperimentContext) -> None:
    w, h = SIZES[ctx.quick]
    lb_ladder = [64] if ctx.quick else [16, 64, 256]
    threads = ctx.threads
    bound_rows, time_rows, over_rows = [], [], []
    for name, setup, edit in _cases(ctx.quick):
        cam = setup.camera.with_resolution(w, h)
        pixels = vc.Relighter(setup, cam, threads=threads)
        converge = pixels.converge_visibility(spp=V_SPP, seed=ctx.seed, progress=ctx.progress)
        cached = vc.Relighter(setup, cam, visibility="cache", threads=threads)
        env = edit(setup)
        ref = vc.render(setup, cam, spp=REFERENCE_SPP[ctx.quick], method="product", jitter=False,
                        envmap=env, seed=ctx.seed + 7, threads=threads, progress=ctx.progress)
        record: dict[str, Any] = {"resolution": [w, h], "converge": converge}
        sources = [("pixels", pixels), ("cache", cached)]
        if setup.scene.area_lights():
            # Area lights read records that see them (not the default: measured here).
            lights = vc.VisibilityCache(setup.scene, preset="medium", nearest_hits=False,
                                        emitters_visible=True)
            lights.build(gbuffer=cached.gbuffer, threads=threads, progress=False)
            sources.append(("cache_lights", vc.Relighter(setup, cam, visibility="cache",
                                                         cache=cached.cache, threads=threads,
                                                         light_cache=lights)))
        for source, rl in sources:
            actual = _decoupled(rl, env, ctx.seed + 1)
            for lb_spp in lb_ladder:
                est = rl.render(envmap=env, lb_spp=lb_spp, lbv_spp=8, seed=ctx.seed + 2)
                share, covered = _bound_holds(est, actual, ref)
                record[f"bound_holds_{source}_lb{lb_spp}"] = share
                bound_rows.append([name, source, lb_spp, f"{100 * share:.1f}%", covered])
            # SBF's regime (its Fig. 1: 8 V-samples against 9): the blend's first frame,
            # and product sampling given its seconds; then both given a longer budget, the
            # blend adding LBV-samples.
            budget = EQUAL_TIME_SECONDS[ctx.quick]
            runs = [(thr, None) for thr in THRESHOLDS] + [(THRESHOLDS[-1], budget)]
            for thr, longer in runs:
                res = rl.render(envmap=env, threshold=thr, lb_spp=EQUAL_TIME_LB_SPP,
                                lbv_spp=8, seed=ctx.seed + 3, time_budget=longer)
                sec = res.stats["seconds"]
                classical = vc.render(setup, cam, method="product", jitter=False, envmap=env,
                                      time_budget=longer or sec, seed=ctx.seed + 4,
                                      threads=threads, progress=False)
                # SBF's classical estimator: <LBV> of the same density (threshold 0, no
                # reuse: no <V> read; one LB-sample, the least the first pass takes),
                # given the same seconds.
                lbv = rl.render(envmap=env, threshold=0.0, lb_spp=1, lbv_spp=8,
                                seed=ctx.seed + 4, time_budget=longer or sec, reuse=False)
                sec = max(sec, classical.stats["seconds"]) if longer else sec
                e_b = vc.metrics.relmse(res.image, ref.image, ref.variance)
                e_c = vc.metrics.relmse(classical.image, ref.image, ref.variance)
                e_l = vc.metrics.relmse(lbv.image, ref.image, ref.variance)
                over = _over_threshold(res.image, ref, thr)
                over_floor = _over_threshold(res.image, ref, thr, RELMSE_FLOOR)
                over_classical = _over_threshold(classical.image, ref, thr, RELMSE_FLOOR)
                record[f"equal_time_{source}_{thr}" + ("_budget" if longer else "")] = {
                    "seconds": sec, "classical_spp": classical.stats["mean_spp"],
                    "blend_lbv_spp": res.stats["lbv_spp_mean"],
                    "relmse": e_b, "relmse_classical": e_c, "ratio": e_b / e_c,
                    "relmse_lbv": e_l, "ratio_lbv": e_b / e_l,
                    "lbv_spp": lbv.stats["lbv_spp_mean"],
                    "over_threshold": over, "over_threshold_floor": over_floor,
                    "over_threshold_floor_classical": over_classical,
                    "mean_t": float(np.nanmean(res.t))}
                time_rows.append([name, source, f"{thr}" + (f" ({longer} s)" if longer else ""),
                                  f"{sec:.3f}", f"{res.stats['lbv_spp_mean']:.1f}",
                                  f"{classical.stats['mean_spp']:.1f}",
                                  f"{e_b:.4f}", f"{e_c:.4f}", f"{e_b / e_c:.2f}",
                                  f"{lbv.stats['lbv_spp_mean']:.1f}", f"{e_l:.4f}",
                                  f"{e_b / e_l:.2f}",
                                  f"{100 * over:.1f}%", f"{100 * over_floor:.1f}%",
                                  f"{100 * over_classical:.1f}%", f"{np.nanmean(res.t):.2f}"])
        # Overhead: the first frame (Var(LB/p) from 64 LB-samples) against a product render
        # of as many shadow rays per pixel, and the later frames per LBV-sample against a
        # product render of as many samples.
        first_frame = pixels.render(envmap=env, lb_spp=64, lbv_spp=8, seed=ctx.seed + 5)
        first = first_frame.stats["first_pass_seconds"]
        blend = pixels.render(envmap=env, lb_spp=64, lbv_spp=8, seed=ctx.seed + 5,
                              time_budget=first + EQUAL_TIME_SECONDS[ctx.quick])
        same_rays = vc.render(setup, cam, spp=8, method="product", jitter=False, envmap=env,
                              seed=ctx.seed + 6, threads=threads, progress=False)
        # The budgeted render's first pass is the first frame's; the driver's passes add:
        # what it took beyond the first frame's 8 LBV-samples, against what it spent beyond
        # the first frame's seconds.
        later_spp = round(blend.stats["lbv_spp_mean"]) - 8
        later = ((blend.stats["seconds"] - first_frame.stats["seconds"]) / max(later_spp, 1))
        same_later = vc.render(setup, cam, spp=max(later_spp, 1), method="product",
                               jitter=False, envmap=env, seed=ctx.seed + 6, threads=threads,
                               progress=False)
        classical_later = same_later.stats["seconds"] / max(later_spp, 1)
        lights = blend.t.shape[-1]
        bytes_per = converge["bytes_per_pixel_and_light"]
        # No later pass when the first spent the budget.
        later_cells = ([f"{1e3 * later:.2f}", f"{1e3 * classical_later:.2f}",
                        f"{later / classical_later - 1:+.0%}"] if later_spp > 0
                       else ["-", "-", "-"])
        over_rows.append([name, f"{first:.3f}", f"{same_rays.stats['seconds']:.3f}",
                          f"{first / same_rays.stats['seconds'] - 1:+.0%}", later_spp,
                          *later_cells, lights, bytes_per])
        record["overhead"] = {"first_frame_seconds": first,
                              "product_8spp_seconds": same_rays.stats["seconds"],
                              "later_lbv_spp": later_spp,
                              "later_seconds_per_sample": later,
                              "product_seconds_per_sample": classical_later,
                              "bytes_per_pixel_and_light": bytes_per}
        if name in CAMERA_MOVES:
            # The last cache relighter: where the scene has area lights, the one whose
            # lights read records too.
            source, mover = sources[-1]
            moved = vc.Camera.look_at(np.array(cam.eye) + CAMERA_MOVES[name],
                                      np.array(cam.eye) + 6 * np.array(cam.forward),
                                      width=w, height=h)
            ref_m = vc.render(setup, moved, spp=REFERENCE_SPP[ctx.quick], method="product",
                              jitter=False, envmap=env, seed=ctx.seed + 8, threads=threads,
                              progress=False)
            actual = _decoupled(mover, env, ctx.seed + 1, camera=moved)
            est = mover.render(envmap=env, lb_spp=64, lbv_spp=8, seed=ctx.seed + 2,
                               camera=moved)
            share, covered = _bound_holds(est, actual, ref_m)
            record["camera_move_bound_holds"] = share
            if est.t.shape[-1] > 1:
                # The area lights' blend factors (the map's is 1 - epsilon in a closed room).
                record["camera_move_mean_t_area"] = float(np.nanmean(est.t[..., 1:]))
            bound_rows.append([name + " (camera moved)", source, 64, f"{100 * share:.1f}%",
                               covered])
        ctx.record(name, record)
    ctx.table(f"Where the estimated bound holds ({w}x{h}, share of covered pixels)",
              ["case", "visibility", "lb_spp", "bound holds", "pixels"], bound_rows)
    ctx.table(f"Equal time: the blend (lb_spp {EQUAL_TIME_LB_SPP}, then LBV-samples) against "
              "product sampling",
              ["case", "visibility", "threshold", "seconds", "blend lbv_spp",
               "product spp (mean)", "relMSE blend", "relMSE product", "ratio",
               "<LBV> spp", "relMSE <LBV>", "ratio to <LBV>",
               "pixels over threshold", "over (floor 1e-2)", "product over (floor 1e-2)",
               "mean t"], time_rows)
    ctx.table("Overhead (pixel visibility) and storage",
              ["case", "first frame s", "product 8 spp s", "first frame overhead",
               "later LBV spp", "later ms per sample", "product ms per sample",
               "later overhead", "lights", "bytes per pixel and light"], over_rows)
    ctx.note("The bound is SBF eq. 7 with estimated variances plus two standard errors of "
             "<V> (pixels: from its effective sample count, plus, after an edit of the map, the "
             "share of the new density the stored samples missed; cache: the spread of the "
             "records it blends); the actual error is that of <LB><V> at lb_spp 1024 against the "
             f"reference, with {NOISE_SIGMAS:g} standard errors of both allowed for their noise.")
