"""``irradiance-cache``: irradiance caching with gradients (survey ch. 3, Fig. 3.1-3.2
analogues) against the one-bounce path tracer and VPLs (issue 62 §4-5).

Per scene (quick: cornell; full: cornell's colour bleeding, garage ``variant="sun"`` (the
sun patch under the roof's edge), room ``variant="sunlit"`` and the six real meshes of
``vc.scenes.load("meshes")`` made all-Lambert, ``meshes-diffuse``) the indirect image of
``render(method="irradiance_cache", direct=False)`` is compared with a reference
``render(method="path", bounces=1, direct=False)`` of many samples (quick: 512 spp at
64x48; full: 1024 at 256x192), cached in the results folder as ``.npz`` (reused by a
rerun with the same size, samples and seed). Outputs:

- the default cache (a = 0.2, 16x64 strata, both gradients, neighbour clamping, 4 spp):
  records, hemisphere and secondary rays, seconds of the build (pass 1) and of the
  interpolating samples (pass 2); its record positions over the image coloured by R_i
  (``{scene}_records.png``), its image, the reference and their difference;
- relMSE on RGB (``vc.metrics.relmse``, the reference's own variance share subtracted)
  for a in {0.05, 0.1, 0.2, 0.4} x gradients {none, rotation, both} x neighbour clamping
  {off, on} (quick: a in {0.1, 0.4} x {none, both} x clamping on), with the records,
  seconds, and what the gradients buy (1 - relMSE(both) / relMSE(none) at equal a);
- equal time: ``"path"`` (bounces=1, direct=False) and ``"vpl"`` (direct=False, the
  default 4096 VPLs) given the default cache's seconds (build included) as
  ``time_budget``, with efficiency 1 / (relMSE * s); ``"vf"`` (direct=False) at its
  defaults, whose seconds its knobs set (its ``budget_factor``: its seconds over the
  cache's); ``"path"`` also at a quarter and four
  times that (full mode), for the relMSE-against-seconds plot; the whole image (direct +
  one bounce: the cache with ``direct=True``, 16 spp) against ``"path"`` (bounces=1,
  direct=True) given its seconds, against a reference that is the sum of the indirect one
  and ``"mis"`` at the same samples;
- near creases (pixels within 8 of a turn of the surface by over 60 degrees: floor-wall
  edges) the relMSE of every grid row, and what neighbour clamping buys there (1 -
  relMSE(on) / relMSE(off) at equal a and gradients);
- records of the default cache built for 256x192, 512x384 and 1024x768 (quick: 64x48,
  128x96, 256x192) and their ratio (Algorithm 1's promise: sparse records).

Targets (issue 62 §5): relMSE at equal time <= 0.1x ``"path"``'s and <= 0.5x ``"vf"``'s
on cornell, garage and room; gradients lower relMSE by >= 30% at equal a; records <= 3x
from 256x192 to 1024x768 (16x the pixels); neighbour clamping lowers relMSE within 8 pixels
of floor-wall edges by >= 20%. results.json, results.md, EXR/PNG images and plots
(``{scene}_relmse_vs_a.png``, ``{scene}_equal_time.png``, ``records_vs_pixels.png``).
``--quick`` runs in about a minute on 2 cores; full mode takes tens of minutes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

import viscache_rs as vc

from ._context import ExperimentContext, pyplot

DESCRIPTION = __doc__

#: Targets of issue 62 §5.
TARGET_PATH_RATIO = 0.1
TARGET_VF_RATIO = 0.5
TARGET_CLAMPING_GAIN = 0.2
#: Width (pixels) of the band about creases where neighbour clamping is measured.
EDGE_BAND_PIXELS = 8
TARGET_GRADIENT_GAIN = 0.3
TARGET_RECORD_RATIO = 3.0

#: Samples per pixel of the cache's renders (the renderer's default): pass 2 antialiases
#: the interpolated bounce and traces Phong's specular part, and estimates direct light in
#: the whole-image rows.
IC_SPP = 16
IC_SPP_DIRECT = 16

#: The scenes that the equal-time target names.
TARGET_SCENES = ("cornell", "garage-sun", "room-sunlit")


def settings(quick: bool) -> dict[str, Any]:
    """Problem size; tests monkeypatch this to shrink the run."""
    if quick:
        return {"scenes": [("cornell", None)], "width": 64, "height": 48,
                "reference_spp": 512, "a": [0.1, 0.4], "gradients": ["none", "both"],
                "clamp": [True], "path_budgets": [1.0], "interpolation_size": (32, 24),
                "scaling": [(64, 48), (128, 96), (256, 192)]}
    return {"scenes": [("cornell", None), ("garage", "sun"), ("room", "sunlit"),
                       ("meshes-diffuse", None)],
            "width": 256, "height": 192, "reference_spp": 1024,
            "a": [0.05, 0.1, 0.2, 0.4], "gradients": ["none", "rotation", "both"],
            "clamp": [False, True], "path_budgets": [0.25, 1.0, 4.0],
            "interpolation_size": (64, 48), "scaling": [(256, 192), (512, 384), (1024, 768)]}


def diffuse_meshes() -> vc.Setup:
    """``vc.scenes.load("meshes")`` with every Phong material made Lambert of its ``kd``:
    a diffuse scene of the real meshes (``../shared/models``)."""
    setup = vc.scenes.load("meshes")
    names = setup.scene.object_names()
    tris = setup.scene.triangles()
    ids = setup.scene.object_ids()
    scene = vc.Scene()
    for k, name in enumerate(names):
        material = setup.scene.material(k)
        if material.kind != "lambert":
            material = vc.Material.lambert(material.params()["kd"])
        t = tris[ids == k]
        scene.add_mesh(t.reshape(-1, 3), np.arange(3 * len(t)).reshape(-1, 3),
                       material=material, name=name)
    return vc.Setup(scene, setup.camera, setup.envmap, name="meshes-diffuse")


def load(name: str, variant: str | None) -> tuple[str, vc.Setup]:
    """The setup and its label (``name-variant``)."""
    if name == "meshes-diffuse":
        return name, diffuse_meshes()
    label = name if variant is None else f"{name}-{variant}"
    return label, vc.scenes.load(name, variant=variant)


def project(camera, points: np.ndarray) -> np.ndarray:
    """Film positions (x, y) in pixels (y down) of world ``points`` (N, 3): the inverse of
    the camera's primary rays."""
    d = np.asarray(points, np.float64) - np.asarray(camera.eye)
    fwd, right, up = (np.asarray(v, np.float64) for v in
                      (camera.forward, camera.right, camera.up))
    z = d @ fwd
    t = np.tan(np.radians(camera.fov_deg) / 2)
    w, h = camera.width, camera.height
    sx, sy = (d @ right) / z, (d @ up) / z
    return np.stack([(sx / (t * w / h) + 1) * w / 2, (1 - sy / t) * h / 2], axis=1)


def reference(ctx: ExperimentContext, label: str, setup, camera, spp: int, method: str,
              **kw) -> dict[str, Any]:
    """A reference render (image, variance, seconds), read from the results folder when a
    run of the same size, samples and seed left it there."""
    path = Path(ctx.out) / (f"reference_{label}_{method}_{camera.width}x{camera.height}_"
                            f"{spp}spp_seed{ctx.seed}.npz")
    if path.exists():
        with np.load(path) as f:
            return {"image": f["image"], "variance": f["variance"],
                    "seconds": float(f["seconds"]), "cached": True}
    res = vc.render(setup, camera=camera, method=method, spp=spp, seed=ctx.seed + 7919,
                    threads=ctx.threads, progress=ctx.progress, **kw)
    image = np.asarray(res.image, np.float64)
    variance = np.asarray(res.variance, np.float64)
    seconds = float(res.stats["seconds"])
    np.savez_compressed(path, image=image, variance=variance, seconds=seconds)
    return {"image": image, "variance": variance, "seconds": seconds, "cached": False}


def errors(image, ref: dict[str, Any]) -> dict[str, Any]:
    """relMSE on RGB (the reference's variance share subtracted), per channel and raw."""
    return {"relmse": vc.metrics.relmse(image, ref["image"], ref["variance"]),
            "relmse_rgb": vc.metrics.relmse_per_channel(image, ref["image"],
                                                        ref["variance"]).tolist(),
            "relmse_raw": vc.metrics.relmse(image, ref["image"]),
            "mean_ratio": (np.asarray(image).mean(axis=(0, 1))
                           / np.maximum(ref["image"].mean(axis=(0, 1)), 1e-12)).tolist()}


def ic_row(res, err: dict[str, Any]) -> dict[str, Any]:
    s = res.stats
    seconds = float(s["seconds"])
    return {"records": int(s["records"]), "seconds": seconds,
            "build_seconds": float(s["build_seconds"]),
            "interpolation_seconds": seconds - float(s["build_seconds"]),
            "hemisphere_rays": int(s["hemisphere_rays"]),
            "secondary_rays": int(s["secondary_rays"]),
            "misses": int(s["irradiance_misses"]), "lookups": int(s["irradiance_lookups"]),
            "clamped_channels": int(s["clamped_channels"]),
            "build_complete": bool(s["build_complete"]),
            **err, "efficiency": vc.metrics.efficiency(err["relmse"], seconds)}


def run(ctx: ExperimentContext) -> None:
    s = settings(ctx.quick)
    ctx.record("settings", s)
    plt = pyplot()
    kw: dict[str, Any] = {"threads": ctx.threads, "progress": ctx.progress}
    summary: dict[str, Any] = {}
    scaling_rows, grid_rows, time_rows, full_rows = [], [], [], []
    noise_floor: dict[str, float] = {}
    for name, variant in s["scenes"]:
        label, setup = load(name, variant)
        cam = setup.camera.with_resolution(s["width"], s["height"])
        ref = reference(ctx, label, setup, cam, s["reference_spp"], "path", bounces=1,
                        direct=False)
        ctx.record(f"{label}/reference", {"spp": s["reference_spp"],
                                          "seconds": ref["seconds"],
                                          "variance": vc.metrics.relative_variance(
                                              ref["variance"], ref["image"]),
                                          "cached": ref["cached"]})

        def ic(cache=None, direct=False, spp=IC_SPP, _setup=setup, _cam=cam, **params):
            return vc.render(_setup, camera=_cam, method="irradiance_cache", direct=direct,
                             spp=spp, seed=ctx.seed, cache=cache, **params, **kw)

        # The default cache: its records over the image, its figures.
        cache = vc.IrradianceCache(setup.scene)
        res = ic(cache)
        default = ic_row(res, errors(res.image, ref))
        default["pixels_per_record"] = cam.width * cam.height / max(default["records"], 1)
        ctx.record(f"{label}/default", default)
        records_figure(ctx, plt, label, cam, cache, res.image, ref)

        # a x gradients x clamping: the render's error, and the interpolation's alone.
        exact = PerPixel(setup, s["interpolation_size"], ctx)
        band = edge_band(setup, cam, ctx.threads)
        grid: list[dict[str, Any]] = []
        for clamp in s["clamp"]:
            for a in s["a"]:
                for g in s["gradients"]:
                    params = {"a": a, "gradients": g, "clamp_neighbours": clamp}
                    r = ic(**params)
                    row = {"a": a, "gradients": g, "clamp": clamp,
                           **ic_row(r, errors(r.image, ref)),
                           "interpolation_relmse": exact.error(params),
                           "edge_relmse": band_error(r.image, ref, band)}
                    grid.append(row)
                    grid_rows.append([label, a, g, "on" if clamp else "off", row["records"],
                                      row["build_seconds"], row["interpolation_seconds"],
                                      row["misses"] / max(row["lookups"], 1), row["relmse"],
                                      rgb(row["relmse_rgb"]), row["efficiency"],
                                      row["interpolation_relmse"]])
        ctx.record(f"{label}/grid", grid)
        ctx.record(f"{label}/per_pixel", exact.figures)
        noise_floor[label] = exact.figures["record_noise"]
        gains = gradient_gains(grid, "relmse")
        interp_gains = gradient_gains(grid, "interpolation_relmse")
        ctx.record(f"{label}/gradient_gain", gains)
        ctx.record(f"{label}/gradient_gain_interpolation", interp_gains)
        clamp_gains = clamping_gains(grid)
        ctx.record(f"{label}/edge_band", {"pixels": int(band.sum()),
                                          "share": float(band.mean()),
                                          "clamping_gain": clamp_gains})
        relmse_vs_a_figure(ctx, plt, label, grid, s)

        # Equal time against paths and VPLs.
        budget = default["seconds"]
        others: list[dict[str, Any]] = []
        for factor in s["path_budgets"]:
            p = vc.render(setup, camera=cam, method="path", bounces=1, direct=False,
                          time_budget=factor * budget, seed=ctx.seed + 1, **kw)
            others.append(other_row("path", factor, p, ref))
        v = vc.render(setup, camera=cam, method="vpl", direct=False, time_budget=budget,
                      seed=ctx.seed + 2, **kw)
        others.append(other_row("vpl", 1.0, v, ref))
        # VF's cost is set by its knobs, not by a budget: its defaults, at their seconds.
        f = vc.render(setup, camera=cam, method="vf", direct=False, seed=ctx.seed + 4, **kw)
        vf_row = vf_figures(f, ref, budget)
        others.append(vf_row)
        ctx.record(f"{label}/equal_time", others)
        path_eq = next(o for o in others if o["method"] == "path" and o["budget_factor"] == 1)
        vpl_eq = next(o for o in others if o["method"] == "vpl")
        ratio_path = ratio(default["relmse"], path_eq["relmse"])
        ratio_vpl = ratio(default["relmse"], vpl_eq["relmse"])
        ratio_vf = ratio(default["relmse"], vf_row["relmse"])
        for o in [{"method": "irradiance_cache (default)", "budget_factor": 1.0,
                   "spp": IC_SPP, "mean_spp": IC_SPP, **default}, *others]:
            time_rows.append([label, o["method"], o["budget_factor"],
                              f"{o['spp']} / {o['mean_spp']:.3g}", o["seconds"],
                              o["relmse"], rgb(o["relmse_rgb"]), o["efficiency"],
                              ratio(o["relmse"], default["relmse"])])
        equal_time_figure(ctx, plt, label, default, grid, others)

        # Direct + one bounce.
        direct_ref = reference(ctx, label, setup, cam, s["reference_spp"], "mis")
        full_ref = {"image": ref["image"] + direct_ref["image"],
                    "variance": ref["variance"] + direct_ref["variance"]}
        icd = ic(direct=True, spp=IC_SPP_DIRECT)
        icd_row = ic_row(icd, errors(icd.image, full_ref))
        pd = vc.render(setup, camera=cam, method="path", bounces=1, direct=True,
                       time_budget=icd_row["seconds"], seed=ctx.seed + 3, **kw)
        pd_row = other_row("path", 1.0, pd, full_ref)
        ctx.record(f"{label}/whole_image", {"irradiance_cache": icd_row, "path": pd_row})
        full_rows.append([label, icd_row["seconds"], icd_row["relmse"], pd_row["seconds"],
                          pd_row["mean_spp"], pd_row["relmse"],
                          ratio(icd_row["relmse"], pd_row["relmse"]),
                          ratio(icd_row["efficiency"], pd_row["efficiency"])])

        # Records against pixels (builds alone).
        counts = []
        for w, h in s["scaling"]:
            c = vc.IrradianceCache(setup.scene)
            rep = c.build(setup.camera.with_resolution(w, h), seed=ctx.seed,
                          envmap=setup.envmap, **kw)
            counts.append({"width": w, "height": h, "records": rep["records"],
                           "points": rep["points"], "seconds": rep["seconds"],
                           "rays": rep["rays"]})
        record_ratio = counts[-1]["records"] / max(counts[0]["records"], 1)
        ctx.record(f"{label}/scaling", {"rows": counts, "ratio": record_ratio})
        scaling_rows.append([label] + [c["records"] for c in counts]
                            + [record_ratio, counts[-1]["seconds"]])

        both = [g["gain"] for g in gains if g["gradients"] == "both"]
        both_interp = [g["gain"] for g in interp_gains if g["gradients"] == "both"]
        summary[label] = {
            "relmse_ratio_to_path": ratio_path, "relmse_ratio_to_vpl": ratio_vpl,
            "relmse_ratio_to_vf": ratio_vf,
            "seconds_ratio_to_vf": default["seconds"] / vf_row["seconds"],
            "efficiency_gain_over_vf": ratio(default["efficiency"], vf_row["efficiency"]),
            "efficiency_gain_over_path": ratio(default["efficiency"], path_eq["efficiency"]),
            "gradient_gain_min": min(both, default=None),
            "gradient_gain_mean": float(np.mean(both)) if both else None,
            "interpolation_gradient_gain_min": min(both_interp, default=None),
            "record_ratio": record_ratio,
            "edge_clamping_gain_min": min((g["gain"] for g in clamp_gains), default=None),
            "whole_image_ratio_to_path": ratio(icd_row["relmse"], pd_row["relmse"]),
            "path_target_met": None if ratio_path is None else ratio_path <= TARGET_PATH_RATIO,
            "vf_target_met": vf_target(default, vf_row),
            "gradient_target_met": (None if not both else
                                    min(both) >= TARGET_GRADIENT_GAIN),
            "record_target_met": record_ratio <= TARGET_RECORD_RATIO,
            "clamping_target_met": (None if not clamp_gains else
                                    min(g["gain"] for g in clamp_gains)
                                    >= TARGET_CLAMPING_GAIN),
        }
        ctx.record(f"{label}/summary", summary[label])
        d = default
        ctx.note(f"### {label}\n\n{cam.width}x{cam.height}; reference: path, 1 bounce, "
                 f"{s['reference_spp']} spp, {ref['seconds']:.3g} s. Default cache: "
                 f"{d['records']} records ({d['pixels_per_record']:.1f} pixels each), "
                 f"{d['hemisphere_rays']} hemisphere + {d['secondary_rays']} secondary rays, "
                 f"build {d['build_seconds']:.3g} s, interpolation ({IC_SPP} spp) "
                 f"{d['interpolation_seconds']:.3g} s, relMSE {d['relmse']:.4g} "
                 f"(R/G/B {rgb(d['relmse_rgb'])}), uncovered samples {d['misses']}.")

    ctx.table("relMSE of the indirect image: a x gradients x neighbour clamping",
              ["scene", "a", "gradients", "clamp", "records", "build s", "interp. s",
               "missed samples", "relMSE", "relMSE R/G/B", "eff 1/(relMSE s)",
               f"interpolation relMSE ({s['interpolation_size'][0]}x"
               f"{s['interpolation_size'][1]} points)"], grid_rows)
    ctx.note("'missed samples' is the share of the render's samples whose hit no record "
             "reached: they take a one-sample path. 'interpolation relMSE' is the error "
             "of the cache's E at a small view's pixel centres against a record at every "
             "pixel (the same record where both have one, records being keyed by pixel): "
             "the interpolation's error without the misses and the samples' noise, but "
             "with the records' own noise on both sides. That noise, measured by per-pixel "
             "records of two seeds, is " + ", ".join(
                 f"{k} {v:.3g}" for k, v in noise_floor.items()) + " (relMSE).")
    ctx.table("Equal time (the default cache's seconds, build included, as time_budget)",
              ["scene", "method", "budget x", "spp (least / mean)", "seconds", "relMSE",
               "relMSE R/G/B",
               "eff 1/(relMSE s)", "relMSE / cache's"], time_rows)
    ctx.table(f"Whole image (direct + one bounce): cache with direct=True ({IC_SPP_DIRECT} "
              "spp) against path given its seconds",
              ["scene", "cache s", "cache relMSE", "path s", "path mean spp", "path relMSE",
               "relMSE ratio", "efficiency gain"], full_rows)
    res_names = [f"{w}x{h}" for w, h in s["scaling"]]
    ctx.table("Records of the default cache against the view's pixels",
              ["scene", *res_names, f"ratio {res_names[-1]}/{res_names[0]}",
               f"build s at {res_names[-1]}"], scaling_rows)
    ctx.table("Targets (issue 62 §5)",
              ["scene", "relMSE / path's (<= 0.1)", "relMSE / vpl's",
               "relMSE / vf's (<= 0.5)",
               "gradient gain min (>= 0.3)", "gradient gain mean",
               "interpolation gradient gain min", "records ratio (<= 3)",
               f"edge clamping gain min (>= {TARGET_CLAMPING_GAIN})",
               "whole image / path's", "met: path, vf, gradients, records, clamping"],
              [[k, v["relmse_ratio_to_path"], v["relmse_ratio_to_vpl"],
                v["relmse_ratio_to_vf"],
                v["gradient_gain_min"], v["gradient_gain_mean"],
                v["interpolation_gradient_gain_min"], v["record_ratio"],
                v["edge_clamping_gain_min"], v["whole_image_ratio_to_path"],
                ", ".join({True: "yes", False: "no", None: "n/a"}[v[f"{t}_target_met"]]
                          for t in ("path", "vf", "gradient", "record", "clamping"))]
               for k, v in summary.items()])
    ctx.note("relMSE is on RGB against the reference, minus the reference's own variance "
             "share (so small values may dip below 0 where the error is within the "
             "reference's noise). 'gradient gain' is 1 - relMSE(both) / relMSE(none) at "
             "equal a and clamping. Seconds are wall-clock on a shared machine: compare "
             "within one run. The equal-time target names " + ", ".join(TARGET_SCENES) + ". "
             "Under a time budget path and vpl sample adaptively: 'spp' gives the least "
             "any pixel took and the mean; a mean above the reference's samples is beyond "
             "what the reference can tell.")
    ctx.record("summary", summary)
    scaling_figure(ctx, plt, s, scaling_rows)


def ratio(x: float, y: float) -> float | None:
    """``x / y`` where both are positive and finite, else None: a relMSE less its
    reference's noise share may be <= 0 where the error is within that noise, and its
    ratio then says nothing."""
    if x > 0 and y > 0 and np.isfinite(x) and np.isfinite(y):
        return x / y
    return None


def rgb(values) -> str:
    return " / ".join(f"{v:.3g}" for v in values)


def other_row(method: str, factor: float, res, ref: dict[str, Any]) -> dict[str, Any]:
    err = errors(res.image, ref)
    seconds = float(res.stats["seconds"])
    pixels = res.image.shape[0] * res.image.shape[1]
    return {"method": method, "budget_factor": factor, "spp": int(res.stats["spp"]),
            "samples": int(res.stats["samples"]),
            "mean_spp": int(res.stats["samples"]) / pixels, "seconds": seconds, **err,
            "efficiency": vc.metrics.efficiency(err["relmse"], seconds)}


def vf_figures(res, ref: dict[str, Any], budget: float) -> dict[str, Any]:
    """VF's row at its defaults: its seconds relative to the cache's (``budget_factor``),
    relMSE and efficiency; VF samples nothing per pixel for indirect light (spp 0)."""
    err = errors(res.image, ref)
    seconds = float(res.stats["seconds"])
    return {"method": "vf", "budget_factor": seconds / budget, "spp": 0, "samples": 0,
            "mean_spp": 0.0, "seconds": seconds, **err,
            "efficiency": vc.metrics.efficiency(err["relmse"], seconds)}


def vf_target(cache: dict[str, Any], vf: dict[str, Any]) -> bool | None:
    """Whether the cache's relMSE is at most TARGET_VF_RATIO of VF's at equal time: read
    off the relMSE where VF took at least the cache's seconds, else off the efficiency
    (the relMSE VF would reach in the cache's time if its error fell as 1 / seconds)."""
    r = ratio(cache["relmse"], vf["relmse"])
    if r is None:
        # The cache's error within its reference's noise, VF's above it: met.
        return True if vf["relmse"] > 0 and np.isfinite(vf["relmse"]) else None
    if vf["seconds"] >= cache["seconds"]:
        return r <= TARGET_VF_RATIO
    gain = ratio(cache["efficiency"], vf["efficiency"])
    return None if gain is None else 1.0 / gain <= TARGET_VF_RATIO


def edge_band(setup, cam, threads, width: int = EDGE_BAND_PIXELS) -> np.ndarray:
    """Pixels within ``width`` pixels of a crease (floor-wall edges and the like): where
    two neighbouring pixels' surfaces turn by more than 60 degrees, both hits. (H, W) bool."""
    g = setup.scene.gbuffer(cam, jitter=False, threads=threads)
    n, hit = np.asarray(g["normal"], np.float64), np.asarray(g["object"]) >= 0
    crease = np.zeros(hit.shape, bool)
    for axis in (0, 1):
        a = [slice(None)] * 2
        b = [slice(None)] * 2
        a[axis], b[axis] = slice(None, -1), slice(1, None)
        turn = ((n[tuple(a)] * n[tuple(b)]).sum(axis=-1) < 0.5) & hit[tuple(a)] & hit[tuple(b)]
        crease[tuple(a)] |= turn
        crease[tuple(b)] |= turn
    # Dilate by `width` in both directions (a square window), rows then columns.
    out = crease.copy()
    for axis in (0, 1):
        grown = out.copy()
        for k in range(1, width + 1):
            lo = [slice(None)] * 2
            hi = [slice(None)] * 2
            lo[axis], hi[axis] = slice(None, -k), slice(k, None)
            grown[tuple(lo)] |= out[tuple(hi)]
            grown[tuple(hi)] |= out[tuple(lo)]
        out = grown
    return out & hit


def band_error(image, ref: dict[str, Any], band: np.ndarray) -> float:
    """relMSE on RGB over the pixels of ``band`` (the reference's variance share
    subtracted); NaN for an empty band."""
    if not band.any():
        return float("nan")
    img = np.asarray(image, np.float64)[band][None]
    return vc.metrics.relmse(img, ref["image"][band][None], ref["variance"][band][None])


def clamping_gains(grid: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """1 - edge relMSE(clamping on) / (off) at every (a, gradients) with both rows."""
    out = []
    for row in grid:
        off = next((r for r in grid if not r["clamp"] and r["a"] == row["a"]
                    and r["gradients"] == row["gradients"]), None)
        if not row["clamp"] or off is None:
            continue
        r = ratio(row["edge_relmse"], off["edge_relmse"])
        if r is not None:
            out.append({"a": row["a"], "gradients": row["gradients"], "gain": 1.0 - r})
    return out


def gradient_gains(grid: list[dict[str, Any]], key: str) -> list[dict[str, Any]]:
    """1 - err(gradients) / err(none) of figure ``key`` at every (a, clamp) that has both
    rows with errors above 0: both gradients first, then rotation alone."""
    out = []
    for g in ("both", "rotation"):
        for row in grid:
            base = next((r for r in grid if r["gradients"] == "none" and r["a"] == row["a"]
                         and r["clamp"] == row["clamp"]), None)
            if row["gradients"] != g or base is None:
                continue
            r = ratio(row[key], base[key])
            if r is not None:
                out.append({"a": row["a"], "clamp": row["clamp"], "gradients": g,
                            "gain": 1.0 - r})
    return out


class PerPixel:
    """The interpolation's error alone, at the G-buffer points of a small view (``size``):
    a cache with a record at every pixel (a = 0.01, so that no record reaches a
    neighbouring pixel) gives each point its own E; a cache built with other parameters
    (same G-buffer and seed) is looked up at the same points. Records are keyed by pixel,
    so a record both make is the same record: what differs is interpolation."""

    def __init__(self, setup, size, ctx: ExperimentContext):
        self.setup, self.ctx = setup, ctx
        cam = setup.camera.with_resolution(*size)
        self.gbuffer = setup.scene.gbuffer(cam, jitter=False, threads=ctx.threads)
        hit = self.gbuffer["object"].ravel() >= 0
        self.points = self.gbuffer["position"].reshape(-1, 3)[hit]
        self.normals = self.gbuffer["normal"].reshape(-1, 3)[hit]
        exact = vc.IrradianceCache(setup.scene, a=0.01)
        report = self.build(exact)
        found = exact.lookup(self.points, self.normals, threads=ctx.threads)
        self.want = found["irradiance"]
        # Points that are not diffuse (black, or Phong with kd = 0) have no records.
        self.keep = ~np.isnan(self.want).any(axis=1)
        # The records' own noise: per-pixel records of another seed against these. Half of
        # it is what one set of records adds to an error measured here; with noisy records
        # (a small sunlit patch seen by few strata) it, not interpolation, dominates.
        other = vc.IrradianceCache(setup.scene, a=0.01)
        self.build(other, seed=ctx.seed + 1)
        again = other.lookup(self.points, self.normals, threads=ctx.threads)["irradiance"]
        noise = vc.metrics.relmse(again[self.keep][None], self.want[self.keep][None]) / 2
        self.figures = {"size": list(size), "points": int(hit.sum()),
                        "records": report["records"], "seconds": report["seconds"],
                        "own_record": float(np.mean(found["weight_sum"][self.keep] == np.inf)),
                        "record_noise": noise}

    def build(self, cache, seed=None):
        return cache.build(gbuffer=self.gbuffer, seed=self.ctx.seed if seed is None else seed,
                           threads=self.ctx.threads, envmap=self.setup.envmap, progress=False)

    def error(self, params: dict[str, Any]) -> float:
        cache = vc.IrradianceCache(self.setup.scene, **params)
        self.build(cache)
        got = cache.lookup(self.points, self.normals, threads=self.ctx.threads)["irradiance"]
        return vc.metrics.relmse(got[self.keep][None], self.want[self.keep][None])


def records_figure(ctx, plt, label, cam, cache, image, ref) -> None:
    """The cache's image with its records over it, coloured by R_i; the reference; the
    difference."""
    recs = cache.records()
    xy = project(cam, recs["position"])
    exposure = 0.5 / max(float(np.percentile(ref["image"], 99)), 1e-6)
    ctx.image(f"{label}_cache", image, exposure=exposure)
    ctx.image(f"{label}_reference", ref["image"], exposure=exposure)
    ctx.image(f"{label}_difference", np.abs(np.asarray(image) - ref["image"]),
              exposure=4 * exposure)
    show = np.clip(np.asarray(image) * exposure, 0, 1) ** (1 / 2.2)
    fig, (a0, a1) = plt.subplots(1, 2, figsize=(12, 4.6))
    a0.imshow(show, interpolation="nearest")
    sc = a0.scatter(xy[:, 0] - 0.5, xy[:, 1] - 0.5, c=recs["radius"], s=4, cmap="viridis",
                    norm="log")
    fig.colorbar(sc, ax=a0, fraction=0.035, pad=0.02, label="R_i (world units)")
    a0.set_xlim(-0.5, cam.width - 0.5)
    a0.set_ylim(cam.height - 0.5, -0.5)
    a0.set_title(f"{label}: {len(cache)} records over the cache's image", fontsize=9)
    a0.axis("off")
    a1.imshow(np.clip(ref["image"] * exposure, 0, 1) ** (1 / 2.2), interpolation="nearest")
    a1.set_title("reference (path, 1 bounce, direct=False)", fontsize=9)
    a1.axis("off")
    ctx.figure(f"{label}_records", fig)


def relmse_vs_a_figure(ctx, plt, label, grid, s) -> None:
    fig, (a0, a1) = plt.subplots(1, 2, figsize=(11, 4))
    for clamp in s["clamp"]:
        for g in s["gradients"]:
            rows = [r for r in grid if r["gradients"] == g and r["clamp"] == clamp]
            style = "-" if clamp else "--"
            tag = f"{g}, clamp {'on' if clamp else 'off'}"
            a0.loglog([r["a"] for r in rows], [max(r["relmse"], 1e-9) for r in rows],
                      style + "o", label=tag, ms=4)
            a1.loglog([r["records"] for r in rows], [max(r["relmse"], 1e-9) for r in rows],
                      style + "o", label=tag, ms=4)
    a0.set_xlabel("a")
    a1.set_xlabel("records")
    for ax in (a0, a1):
        ax.set_ylabel("relMSE (RGB)")
        ax.legend(fontsize=7)
    a0.set_title(f"{label}: relMSE against a", fontsize=9)
    a1.set_title(f"{label}: relMSE against records", fontsize=9)
    fig.tight_layout()
    ctx.figure(f"{label}_relmse_vs_a", fig)


def equal_time_figure(ctx, plt, label, default, grid, others) -> None:
    fig, ax = plt.subplots(figsize=(5.5, 4))
    ax.loglog([r["seconds"] for r in grid], [max(r["relmse"], 1e-9) for r in grid], "o",
              color="tab:blue", ms=4, alpha=0.6, label="irradiance cache (grid)")
    ax.loglog([default["seconds"]], [max(default["relmse"], 1e-9)], "*", color="tab:blue",
              ms=12, label="irradiance cache (default)")
    paths = [o for o in others if o["method"] == "path"]
    ax.loglog([o["seconds"] for o in paths], [o["relmse"] for o in paths], "k-s", ms=5,
              label="path, 1 bounce")
    vpl = [o for o in others if o["method"] == "vpl"]
    ax.loglog([o["seconds"] for o in vpl], [o["relmse"] for o in vpl], "r^", ms=7,
              label="vpl (4096)")
    vf = [o for o in others if o["method"] == "vf"]
    ax.loglog([o["seconds"] for o in vf], [max(o["relmse"], 1e-9) for o in vf], "gD", ms=6,
              label="vf (defaults)")
    ax.set_xlabel("seconds (build included)")
    ax.set_ylabel("relMSE (RGB)")
    ax.set_title(f"{label}: indirect light, relMSE against time", fontsize=9)
    ax.legend(fontsize=7)
    ctx.figure(f"{label}_equal_time", fig)


def scaling_figure(ctx, plt, s, rows) -> None:
    fig, ax = plt.subplots(figsize=(5, 3.6))
    pixels = [w * h for w, h in s["scaling"]]
    for row in rows:
        ax.loglog(pixels, row[1:1 + len(pixels)], "o-", label=row[0])
    if rows:
        ax.loglog(pixels, [rows[0][1] * p / pixels[0] for p in pixels], ":", color="gray",
                  label=f"{rows[0][0]} x pixels")
    ax.set_xlabel("pixels")
    ax.set_ylabel("records")
    ax.set_title("records of the default cache against the view's size", fontsize=9)
    ax.legend(fontsize=7)
    ctx.figure("records_vs_pixels", fig)

