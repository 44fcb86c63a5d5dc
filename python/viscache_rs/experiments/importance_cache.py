"""``importance-cache``: importance caching for many lights (survey ch. 6, Fig. 6.8
analogue) against the exact sum over the lights (issue 65 §4-5).

Per light set (quick: cornell with 2,000 importance-driven VPLs at 64x48; full: cornell
with 10,000, garage ``variant="sun"`` with its sun and sky as about 1,000 directional
lights (``VPLs.from_envmap(level=5)``) plus 2,000 surface VPLs, garage
``variant="ceiling_lights"`` as its 1,000 small area lights (``VPLs.from_area_lights``)
plus 1,000 surface VPLs, and garden (foliage: hard visibility) with 10,000 VPLs, at
256x192) every render shades the pixels' centres (``jitter=False``), so the reference is
the exact sum of eq. 6.1 (``method="vpl"``, one shadow ray per light and pixel; for area
lights a fresh point on each per sample: 32 samples there, whose own variance the relMSE
subtracts).

Methods, the columns of Fig. 6.8: ``vpl_sampled`` with ``sampling="uniform"``,
``"power"`` and ``"unoccluded"`` (the per-pixel product without visibility, exact but
paying for every light at every pixel), and ``method="importance_cache"`` with one row
alone (``combine="F"``, ``"U"``, ``"B"``: biased where that row misses a light, shown for
comparison), ``"balance"`` (Fig. 6.7a's p_b) and ``"alpha_max"`` (eq. 6.6, the default).

Equal time: every method first renders ``base_spp`` samples per pixel (16; quick 8) of
35 lights each (``vpl_samples=35``; the cache's rows share them: ``vpl_samples`` is per
row, so the combined methods get 35 // 4 per row; at the pixels' centres the samples only
add draws); the fastest of those sets the time every method is then given
(``time_budget``, the cache's build included). Outputs: relMSE on RGB against the exact
sum, efficiency 1 / (relMSE s), relMSE against seconds (a quarter, one and four times the
budget), each method's image and error map, the cache's build seconds, records and bytes,
and an image of the rows that claim each pixel's lights (Fig. 6.7b): per pixel, the mass
of the rows' mean pmf (1/4) sum_s p_s over the lights each row owns under alpha-max, as
red F, green U, blue B, grey C. results.json, results.md, PNG images and plots.

Targets (issue 65 §5): at equal time alpha_max's relMSE <= 0.2x uniform's, <= 0.5x
power's, <= 0.7x balance's and never above the best single row's by more than 15%; on
cornell with 10,000 VPLs relMSE 0.01 in <= 1/50 of the exact sum's time; build <= 0.5 us
per record-light pair; <= 12 bytes per light per record.
"""

from __future__ import annotations

from typing import Any

import numpy as np

import viscache_rs as vc

from ._context import ExperimentContext, pyplot

DESCRIPTION = __doc__

#: Targets of issue 65 §5.
TARGET_UNIFORM, TARGET_POWER, TARGET_BALANCE, TARGET_BEST_ROW = 0.2, 0.5, 0.7, 1.15
TARGET_EXACT_FRACTION, TARGET_RELMSE = 1 / 50, 0.01
TARGET_BUILD_US, TARGET_BYTES = 0.5, 12.0

#: Lights per pixel at equal time (Fig. 6.8: 35 for the fastest method).
LIGHTS_PER_PIXEL = 35

#: The columns: label, method, keyword arguments.
METHODS: list[tuple[str, str, dict[str, Any]]] = [
    ("uniform", "vpl_sampled", {"sampling": "uniform"}),
    ("power", "vpl_sampled", {"sampling": "power"}),
    ("unoccluded", "vpl_sampled", {"sampling": "unoccluded"}),
    ("F", "importance_cache", {"combine": "F"}),
    ("U", "importance_cache", {"combine": "U"}),
    ("B", "importance_cache", {"combine": "B"}),
    ("balance", "importance_cache", {"combine": "balance"}),
    ("alpha_max", "importance_cache", {"combine": "alpha_max"}),
]
ROWS = ("F", "U", "B")


def settings(quick: bool) -> dict[str, Any]:
    """Problem size; tests monkeypatch this to shrink the run."""
    if quick:
        return {"sets": [("cornell", 2000)], "width": 128, "height": 96, "base_spp": 8,
                "budgets": [0.5, 1.0, 2.0], "area_reference_spp": 64}
    return {"sets": [("cornell", 10000), ("garage-sun", 2000),
                     ("garage-ceiling_lights", 1000), ("garden", 10000)],
            "width": 256, "height": 192, "base_spp": 16, "budgets": [0.25, 1.0, 4.0],
            "area_reference_spp": 32}


def light_set(label: str, count: int, seed: int, threads) -> tuple[vc.Setup, Any, bool]:
    """The setup, its lights and whether they hold area lights (whose exact sum needs many
    samples: each sample draws a point on every light)."""
    name, _, variant = label.partition("-")
    setup = vc.scenes.load(name, variant=variant or None)
    if variant == "sun":
        # Sun and sky as directional lights, the indirect light as surface VPLs.
        sky = vc.VPLs.from_envmap(setup, level=5)
        bounce = vc.VPLs.trace(setup, count, seed=seed, importance=True, lights=False,
                               threads=threads)
        return setup, sky + bounce, False
    if variant == "ceiling_lights":
        lamps = vc.VPLs.from_area_lights(setup.scene)
        bounce = vc.VPLs.trace(setup, count, seed=seed, importance=True, lights=False,
                               threads=threads)
        return setup, lamps + bounce, True
    return setup, vc.VPLs.trace(setup, count, seed=seed, importance=True,
                                threads=threads), False


def errors(image, ref: dict[str, Any]) -> dict[str, Any]:
    """relMSE on RGB against the exact sum (its own variance share subtracted where it has
    one), per channel, and the ratio of the means."""
    var = ref["variance"]
    return {"relmse": vc.metrics.relmse(image, ref["image"], var),
            "relmse_rgb": vc.metrics.relmse_per_channel(image, ref["image"], var).tolist(),
            "mean_ratio": (np.asarray(image).mean(axis=(0, 1))
                           / np.maximum(ref["image"].mean(axis=(0, 1)), 1e-12)).tolist()}


def run(ctx: ExperimentContext) -> None:
    s = settings(ctx.quick)
    ctx.record("settings", s)
    plt = pyplot()
    kw: dict[str, Any] = {"threads": ctx.threads, "progress": ctx.progress, "jitter": False,
                          "seed": ctx.seed}
    summary: dict[str, Any] = {}
    for label, count in s["sets"]:
        setup, lights, area = light_set(label, count, ctx.seed, ctx.threads)
        cam = setup.camera.with_resolution(s["width"], s["height"])

        def render(method, _setup=setup, _cam=cam, _lights=lights, **params):
            return vc.render(_setup, camera=_cam, method=method, vpls=_lights, **params,
                             **kw)

        # The exact sum: one sample per pixel (point lights), many with area lights.
        ref_spp = s["area_reference_spp"] if area else 1
        exact = render("vpl", spp=ref_spp)
        image = np.asarray(exact.image, np.float64)
        ref: dict[str, Any] = {"image": image, "seconds": float(exact.stats["seconds"]),
               "variance": (np.asarray(exact.variance, np.float64) if area
                            else np.zeros_like(image))}
        ctx.record(f"{label}/exact", {"lights": len(lights), "spp": ref_spp,
                                      "seconds": ref["seconds"],
                                      "shadow_rays": int(exact.stats["shadow_rays"])})
        exposure = 0.5 / max(float(np.percentile(ref["image"], 99)), 1e-6)
        ctx.image(f"{label}_exact", ref["image"], exposure=exposure)

        # A cache of the view's records: its build, records and bytes, the rows' claims.
        cache = vc.ImportanceCache(setup.scene, lights)
        report = cache.build(cam, seed=ctx.seed, threads=ctx.threads, progress=ctx.progress)
        pairs = max(len(cache) * len(lights), 1)
        build = {"records": len(cache), "seconds": float(report["seconds"]),
                 "us_per_pair": 1e6 * float(report["seconds"]) / pairs,
                 "bytes": int(cache.memory_bytes()),
                 "bytes_per_light_record": cache.memory_bytes() / pairs}
        ctx.record(f"{label}/build", build)
        claims = row_claims(setup, cam, cache, ctx.threads)
        ctx.record(f"{label}/row_claims", {r: float(claims[..., i].mean())
                                            for i, r in enumerate("FUBC")})
        ctx.image(f"{label}_row_claims", claims[..., :3] + claims[..., 3:] * 0.5)

        # 35 lights per pixel each: the fastest sets the equal time.
        fixed = []
        for name, method, params in METHODS:
            n = LIGHTS_PER_PIXEL if method == "vpl_sampled" else LIGHTS_PER_PIXEL // 4
            res = render(method, spp=s["base_spp"], vpl_samples=n, **params)
            fixed.append({"method": name, "seconds": float(res.stats["seconds"]),
                          **errors(res.image, ref)})
        ctx.record(f"{label}/fixed_samples", fixed)
        budget = min(r["seconds"] for r in fixed)

        rows: list[dict[str, Any]] = []
        for factor in s["budgets"]:
            for name, method, params in METHODS:
                n = LIGHTS_PER_PIXEL if method == "vpl_sampled" else LIGHTS_PER_PIXEL // 4
                res = render(method, vpl_samples=n, time_budget=factor * budget, **params)
                st = res.stats
                row = {"method": name, "budget_factor": factor,
                       "seconds": float(st["seconds"]), "spp": int(st["spp"]),
                       **errors(res.image, ref)}
                row["efficiency"] = vc.metrics.efficiency(row["relmse"], row["seconds"])
                if method == "importance_cache":
                    row["build_seconds"] = float(st["build_seconds"])
                rows.append(row)
                if factor == 1.0:
                    ctx.image(f"{label}_{name}", res.image, exposure=exposure)
                    ctx.image(f"{label}_{name}_error",
                              np.abs(np.asarray(res.image) - ref["image"]),
                              exposure=4 * exposure)
        ctx.record(f"{label}/equal_time", rows)
        equal = {r["method"]: r for r in rows if r["budget_factor"] == 1.0}
        ctx.table(f"{label}: {len(lights)} lights, equal time {budget:.3g} s "
                  f"(exact sum {ref['seconds']:.3g} s)",
                  ["method", "seconds", "spp", "relMSE", "efficiency", "mean ratio (G)"],
                  [[m, r["seconds"], r["spp"], r["relmse"], r["efficiency"],
                    r["mean_ratio"][1]] for m, r in equal.items()])
        summary[label] = verdict(equal, build, ref["seconds"])
        curve_figure(ctx, plt, label, rows)
    ctx.record("summary", summary)
    ctx.table("Targets (issue 65 §5): alpha_max's relMSE over each column's at equal time",
              ["set", "/ uniform (<= 0.2)", "/ power (<= 0.5)", "/ balance (<= 0.7)",
               "/ best row (<= 1.15)", "s to relMSE 0.01 / exact sum's (<= 0.02)",
               "us per pair (<= 0.5)", "bytes per light and record (<= 12)"],
              [[k, v["ratio_uniform"], v["ratio_power"], v["ratio_balance"],
                v["ratio_best_row"], v["seconds_to_target_over_exact"], v["us_per_pair"],
                v["bytes_per_light_record"]] for k, v in summary.items()])
    ctx.note("relMSE is on RGB against the exact sum of eq. 6.1 over the same lights at "
             "the pixels' centres (its own variance subtracted where area lights make it "
             "noisy). The rows F, U, B alone are biased where they miss a light. Seconds "
             "include the cache's build; they are wall-clock on a possibly shared machine.")


def verdict(equal: dict[str, dict[str, Any]], build: dict[str, Any],
            exact_seconds: float) -> dict[str, Any]:
    """alpha_max against the other columns at equal time, and the targets met."""
    a = equal["alpha_max"]["relmse"]
    best_row = min(equal[r]["relmse"] for r in ROWS)
    out = {"ratio_uniform": a / equal["uniform"]["relmse"],
           "ratio_power": a / equal["power"]["relmse"],
           "ratio_balance": a / equal["balance"]["relmse"],
           "ratio_best_row": a / best_row,
           "seconds_over_exact": equal["alpha_max"]["seconds"] / exact_seconds,
           # relMSE falls as 1 / seconds: the seconds alpha_max needs for TARGET_RELMSE.
           "seconds_to_target_over_exact": (equal["alpha_max"]["seconds"]
                                            * equal["alpha_max"]["relmse"] / TARGET_RELMSE
                                            / exact_seconds),
           "us_per_pair": build["us_per_pair"],
           "bytes_per_light_record": build["bytes_per_light_record"]}
    out["met"] = {"uniform": out["ratio_uniform"] <= TARGET_UNIFORM,
                  "power": out["ratio_power"] <= TARGET_POWER,
                  "balance": out["ratio_balance"] <= TARGET_BALANCE,
                  "best_row": out["ratio_best_row"] <= TARGET_BEST_ROW,
                  "exact_fraction": out["seconds_to_target_over_exact"]
                  <= TARGET_EXACT_FRACTION,
                  "build": out["us_per_pair"] <= TARGET_BUILD_US,
                  "bytes": out["bytes_per_light_record"] <= TARGET_BYTES}
    return out


def row_claims(setup, cam, cache, threads) -> np.ndarray:
    """(H, W, 4): per pixel centre, the mass of the rows' mean pmf (1/4) sum_s p_s over
    the lights each row (F, U, B, C) owns under alpha-max (eq. 6.6, the cache's alpha);
    zeros where the camera sees no diffuse surface or no record is in reach (C alone)."""
    g = setup.scene.gbuffer(cam, jitter=False, threads=threads)
    hit = np.asarray(g["object"]).ravel() >= 0
    points = np.asarray(g["position"]).reshape(-1, 3)[hit]
    normals = np.asarray(g["normal"]).reshape(-1, 3)[hit]
    found = cache.lookup(points, normals)
    rec = cache.records()
    rows = []
    for name in ("F", "U", "B"):
        v = np.asarray(rec[name], np.float64)
        total = v.sum(axis=1, keepdims=True)
        rows.append(np.divide(v, total, out=np.zeros_like(v), where=total > 0))
    alpha = np.asarray(cache.params["alpha"], np.float64)
    n = rows[0].shape[1]
    out = np.zeros((hit.size, 4))
    claims = np.zeros((len(points), 4))
    for i, ids in enumerate(np.asarray(found["ids"])):
        ids = ids[ids >= 0]
        p = np.zeros((4, n))
        for s_, row in enumerate(rows):
            served = ids[row[ids].sum(axis=1) > 0]
            if len(served):
                p[s_] = row[served].mean(axis=0)
        p[3] = 1.0 / n
        owner = np.full(n, 3)
        for s_ in (2, 1, 0):
            ok = (p[s_] > 0) & np.all(p[s_ + 1:] * alpha[s_ + 1:, None] <= p[s_], axis=0)
            owner = np.where(ok, s_, owner)
        mix = p.mean(axis=0)
        claims[i] = np.bincount(owner, weights=mix, minlength=4)
    out[hit] = claims
    return out.reshape(cam.height, cam.width, 4)


def curve_figure(ctx, plt, label, rows) -> None:
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for name, _, _ in METHODS:
        mine = sorted((r for r in rows if r["method"] == name), key=lambda r: r["seconds"])
        ax.loglog([r["seconds"] for r in mine], [max(r["relmse"], 1e-9) for r in mine],
                  "o-", ms=4, label=name)
    ax.set_xlabel("seconds (the cache's build included)")
    ax.set_ylabel("relMSE (RGB) against the exact sum")
    ax.set_title(f"{label}: relMSE against time", fontsize=9)
    ax.legend(fontsize=7)
    ctx.figure(f"{label}_relmse_vs_seconds", fig)
