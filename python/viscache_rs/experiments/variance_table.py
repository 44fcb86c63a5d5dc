"""CAM08 Tables 2-3 and Fig. 13: product sampling against product sampling with the cache's
control variate, per scene and sample count.

For garage, dynamics and garden (the paper's three scenes), at 10/30/100/300 samples per
pixel: seconds of product sampling and of the control variate (alpha = 1 as in the paper,
and alpha estimated from neighbouring pixels), the overhead in seconds and percent (render
alone, and with the cache build amortised over one frame), and the variance ratio per RGB
channel (the mean over pixels of the variance of the mean, control variate over product;
``vc.metrics.variance_ratio``) beside the mean of the three: no channel is weighted down.
Table 2: records, record size and the cache's amortised shadow rays per pixel. Fig. 13: an
equal-time comparison on garage (cv at 30 spp against product at the spp that takes the
same time), with the images side by side.

Both methods shade one point per pixel and draw every sample there (CAM08's setting), with
the same product cells, seeds and threads; the
cache is built once per scene (``CACHE`` below). Every render is a point of a sweep
(``vc.experiments.sweep``), each starting from the cache as built; on a cluster
(``--scheduler``) its seconds are those of one thread. ``--quick`` renders 256x192 at 10/30/100
spp; the full mode 640x480 at 10/30/100/300.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from ._context import ExperimentContext, pyplot

DESCRIPTION = __doc__

#: Renders per configuration whose least time is reported (they are identical images).
REPEATS = 2
# The paper's setting: every sample at the first hit through the pixel's centre, the
# environment by plain product sampling (the tables compare estimators at fixed points).
CAM08_POINTS: dict[str, Any] = {"jitter": False, "technique_weights": {"product": 1}}

#: Cache settings per scene. Record resolutions: 64^2 for garage and dynamics (CAM08 Table 2
#: used 32^2 for garage; 64^2 halves the variance left on its glossy cars), 32^2 for garden.
#: Garden's grass changes visibility from pixel to pixel, so §5.2 would ask for a record at
#: nearly every pixel; it gets the ``low`` preset capped at 2% of the pixels (CAM08: 17,100
#: records at 1600x1200, 0.9%). The control variate never reads R_i, so no cache traces it.
CACHE: dict[str, dict[str, Any]] = {
    "garage": {"resolution": 64, "preset": "medium", "nearest_hits": False},
    "dynamics": {"resolution": 64, "preset": "medium", "nearest_hits": False},
    "garden": {"resolution": 32, "preset": "low", "records_per_pixel": 0.02,
               "nearest_hits": False},
}


def cache_settings(name: str, pixels: int, seed: int) -> dict[str, Any]:
    """The settings of ``CACHE[name]`` for an image of ``pixels`` pixels, as a sweep
    point's ``cache`` (built once per scene and shared by its points)."""
    cfg = dict(CACHE[name])
    share = cfg.pop("records_per_pixel", None)
    if share is not None:
        cfg["max_records"] = max(1, int(share * pixels))
    return {**cfg, "seed": seed}


def settings(quick: bool) -> dict:
    """Image size, sample counts and scenes of a run."""
    if quick:
        return {"width": 256, "height": 192, "spp": [10, 30, 100],
                "scenes": ["garage", "dynamics", "garden"], "equal_time_spp": 30}
    return {"width": 640, "height": 480, "spp": [10, 30, 100, 300],
            "scenes": ["garage", "dynamics", "garden"], "equal_time_spp": 30}


#: The three renders of every (scene, spp): label -> method and parameters.
METHODS: dict[str, tuple[str, dict[str, Any]]] = {
    "product": ("product", {}),
    "cv": ("cv", {"alpha": 1.0}),
    "cv_est": ("cv", {"alpha": "estimate"}),
}


def points(cfg: dict, seed: int) -> list[dict[str, Any]]:
    """The sweep's points: per scene and spp, product and cv (alpha 1 and estimated) at
    CAM08's fixed points, timed as the least of ``REPEATS`` renders; the first spp keeps
    its images; garage adds Fig. 13's cv render. No reference: the tables compare
    variances."""
    common = {"width": cfg["width"], "height": cfg["height"], "reference": False,
              "repeats": REPEATS, "scene_seed": seed}
    out = []
    for name in cfg["scenes"]:
        cache = cache_settings(name, cfg["width"] * cfg["height"], seed)
        for spp in cfg["spp"]:
            for label, (method, params) in METHODS.items():
                out.append({**common, "scene": name, "label": label, "method": method,
                            "spp": spp, "seed": seed + spp,
                            "params": {**params, **CAM08_POINTS},
                            "cache": cache if method == "cv" else None,
                            "image": spp == cfg["spp"][0] and label != "cv_est"})
        if name == "garage":
            out.append({**common, "scene": name, "label": "equal_time_cv", "method": "cv",
                        "spp": cfg["equal_time_spp"], "seed": seed + 1000, "repeats": 1,
                        "params": {"alpha": "estimate", **CAM08_POINTS}, "cache": cache,
                        "image": True})
    return out


def channel_ratios(row, base) -> tuple[list[float], float]:
    """Per-channel variance ratios of sweep row ``row`` to row ``base`` (their mean
    per-pixel variances, ``vc.metrics.variance_ratio``) and their mean."""
    ratios = [float(row[c] / base[c]) if base[c] > 0 else float("nan")
              for c in ("var_r", "var_g", "var_b")]
    return ratios, float(np.mean(ratios))


def _stat(row, key: str) -> Any:
    return json.loads(row["stats"]).get(key)


def run(ctx: ExperimentContext) -> None:
    cfg = settings(ctx.quick)
    ctx.record("settings", cfg)
    table3, table2 = [], []
    per_scene = {}
    table = ctx.sweep(points(cfg, ctx.seed))
    for name in cfg["scenes"]:
        at = table[table["scene"] == name]
        first = at[at["method"] == "cv"].iloc[0]
        build = {"records": int(first["records"]), "seconds": float(first["cache_seconds"]),
                 "shadow_rays": int(first["cache_shadow_rays"]),
                 "shadow_rays_per_pixel": float(first["cache_rays_per_pixel"])}
        res = json.loads(first["cache"]).get("resolution") or CACHE[name].get("resolution")
        table2.append([name, build["records"], f"{res}x{res}",
                       round(first["cache_memory_bytes"] / max(build["records"], 1)),
                       build["shadow_rays_per_pixel"], build["seconds"]])
        rows = []
        for spp in cfg["spp"]:
            got = {r["label"]: r for r in at[at["spp"] == spp].to_dict("records")
                   if r["label"] in METHODS}
            prod, cv1, cve = got["product"], got["cv"], got["cv_est"]
            t_p = prod["render_seconds"]
            row = {"spp": spp, "time_product": t_p, "var_product": prod["mean_variance"]}
            for key, r in (("cv", cv1), ("cv_est", cve)):
                t = r["render_seconds"]
                per_channel, mean_ratio = channel_ratios(r, prod)
                row.update({
                    f"time_{key}": t,
                    f"overhead_{key}_s": t - t_p,
                    f"overhead_{key}_pct": 100 * (t - t_p) / t_p,
                    f"overhead_{key}_with_build_pct": 100 * (t + build["seconds"] - t_p) / t_p,
                    f"var_{key}": r["mean_variance"],
                    f"ratio_{key}": mean_ratio,
                    f"ratio_rgb_{key}": per_channel,
                    f"lookup_s_{key}": _stat(r, "lookup_seconds"),
                    f"control_s_{key}": _stat(r, "control_seconds"),
                    f"miss_rate_{key}": _stat(r, "miss_rate"),
                })
            row["mean_alpha_est"] = _stat(cve, "mean_alpha")
            rows.append(row)
            table3.append([name, spp, t_p, row["time_cv"], row["overhead_cv_s"],
                           f"{row['overhead_cv_pct']:.1f}%",
                           f"{row['overhead_cv_with_build_pct']:.1f}%",
                           _rgb(row["ratio_rgb_cv"]), row["ratio_cv"],
                           _rgb(row["ratio_rgb_cv_est"]), row["ratio_cv_est"]])
            if spp == cfg["spp"][0]:
                ctx.image(f"{name}_product_{spp}spp", prod["image"])
                ctx.image(f"{name}_cv_{spp}spp", cv1["image"])
        per_scene[name] = {"build": build, "rows": rows}
        if name == "garage":
            cv = at[at["label"] == "equal_time_cv"].iloc[0]
            _equal_time(ctx, cv, rows, build["seconds"])
    ctx.record("scenes", per_scene)
    ctx.table("Table 2: the caches", ["scene", "records", "record size", "bytes/record",
                                      "avg rays/pixel", "build s"], table2)
    ctx.table("Table 3: product vs control variate",
              ["scene", "spp", "time product s", "time cv s", "overhead s", "overhead",
               "overhead incl. build", "variance ratio R/G/B (alpha=1)", "mean",
               "variance ratio R/G/B (alpha est.)", "mean"], table3)
    _plot(ctx, per_scene)


def _rgb(ratios) -> str:
    return " / ".join(f"{r:.3f}" for r in ratios)


def _equal_time(ctx, cv, rows, build_seconds) -> None:
    """Fig. 13: cv (the sweep's row ``cv``) against product at the spp that takes as long,
    with the cache reused (render time only) and with its build counted."""
    # Render time is close to a + b * spp (per-pixel setup plus samples); fit the ladder.
    spp = np.array([r["spp"] for r in rows], float)
    tp = np.array([r["time_product"] for r in rows], float)
    b, a = np.polyfit(spp, tp, 1) if len(spp) > 1 else (tp[0] / spp[0], 0.0)
    # Tiny or noisy timings can fit a flat or falling line: bound the cost per sample below.
    b = max(b, 0.1 * tp[-1] / spp[-1])
    t_cv = float(cv["render_seconds"])
    cv_spp = int(cv["spp"])
    out = {"cv_spp": cv_spp, "cv_seconds": t_cv, "cache_build_seconds": build_seconds}
    table = [["cv (alpha est.)", cv_spp, t_cv, cv["mean_variance"], "1 / 1 / 1"]]
    budgets = {"render": t_cv, "with_build": t_cv + build_seconds}
    # At least two samples, so the variance of the mean is defined.
    products = {label: int(np.clip(round((budget - a) / b), 2, 1 << 16))
                for label, budget in budgets.items()}
    common = {"scene": cv["scene"], "method": "product", "width": int(cv["width"]),
              "height": int(cv["height"]), "reference": False, "seed": ctx.seed + 2000,
              "scene_seed": int(cv["scene_seed"]), "params": CAM08_POINTS, "image": True}
    prods = ctx.sweep([{**common, "label": label, "spp": n} for label, n in products.items()])
    images = {}
    for prod in prods.to_dict("records"):
        label = prod["label"]
        per_channel, ratio = channel_ratios(cv, prod)
        out[label] = {"product_spp": products[label], "product_seconds": prod["render_seconds"],
                      "variance_ratio": ratio, "variance_ratio_rgb": per_channel}
        table.append([f"product, equal time ({label.replace('_', ' ')})", products[label],
                      prod["render_seconds"], prod["mean_variance"], _rgb(per_channel)])
        images[label] = prod["image"]
    ctx.record("equal_time", out)
    ctx.table("Fig. 13: equal time on garage",
              ["method", "spp", "seconds", "mean variance (RGB)", "cv variance / this, R/G/B"],
              table)
    gap = np.ones_like(cv["image"][:, :4])
    both = np.concatenate([images["render"], gap, cv["image"]], axis=1)
    ctx.image("garage_equal_time_product_vs_cv", both)


def _plot(ctx, per_scene) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for name, data in per_scene.items():
        spp = [r["spp"] for r in data["rows"]]
        axes[0].plot(spp, [r["ratio_cv"] for r in data["rows"]], "o-", label=f"{name} alpha=1")
        axes[0].plot(spp, [r["ratio_cv_est"] for r in data["rows"]], "s--",
                     label=f"{name} alpha est.")
        axes[1].plot(spp, [r["overhead_cv_pct"] for r in data["rows"]], "o-", label=name)
    axes[0].axhline(1.0, color="grey", lw=0.8)
    axes[0].set(xscale="log", xlabel="samples per pixel", ylabel="variance ratio cv / product",
                title="Variance ratio (CAM08 Table 3)")
    axes[1].set(xscale="log", xlabel="samples per pixel", ylabel="render time overhead %",
                title="Time overhead (render only)")
    axes[0].legend(fontsize=7)
    axes[1].legend(fontsize=7)
    ctx.figure("variance_table", fig)
