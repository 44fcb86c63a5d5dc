"""Error against time for every way of rendering a view: the plot to pick a setting by."""

from __future__ import annotations

import numpy as np

from ._context import pyplot

DESCRIPTION = """\
relMSE on RGB against seconds for product, cv (α = 1 and estimated) with the default \
"auto" cache and the presets (low/medium/high), with efficiency 1/(relMSE·s); the plot \
users look at to pick a setting.

Per scene (garage and dynamics; garden too in full mode) a reference image is rendered by
product importance sampling with many samples per pixel and another seed (quick: 2048 spp
at 96x72; full: 4096 spp at 256x192). Configurations: product; cv with the default cache
(preset "auto": 64^2 records and the coherence check) with alpha = 1 and estimated; cv
with alpha = 1 and estimated over caches built with the low, medium and high preset at
record resolution 32; and cv alpha = 1 over a medium cache at resolution 64. Each cache is
built once per scene (alpha = 1 and alpha estimated share it) and reused across the spp
ladder (quick: 4, 16, 64; full: 4 to 256), as a user would; its build seconds are reported
separately and added in the "total" columns. Renders use the renderer's defaults
(antialiased, jittered samples). Every render is a point of one sweep
(``vc.experiments.sweep``): each starts from the cache as built, and with a cluster
(``viscache experiment tradeoff --scheduler ADDRESS``) the points run one per worker core.

The error is relMSE on RGB (``vc.metrics.relmse``): the mean over pixels and channels of
(img - ref)^2 / (ref^2 + 1e-2), minus the reference's own share, var_ref / (ref^2 + 1e-2)
(both images are unbiased and independent, so what is left estimates the image's error).
The mean per-pixel variance share the renderer reports is given beside it (it is an upper
bound for stratified samples). Efficiency is 1 / (relMSE * seconds), for the render alone
and with the build. Seconds are wall-clock on a shared machine: compare within one run.
"""

#: (label, preset, record resolution, alpha) of every cv configuration; resolution None is
#: the preset's own.
CV_CONFIGS = [
    ("cv auto a=1", "auto", None, 1.0),
    ("cv auto a=est", "auto", None, "estimate"),
    ("cv a=1 low", "low", 32, 1.0),
    ("cv a=1 medium", "medium", 32, 1.0),
    ("cv a=1 high", "high", 32, 1.0),
    ("cv a=est low", "low", 32, "estimate"),
    ("cv a=est medium", "medium", 32, "estimate"),
    ("cv a=est high", "high", 32, "estimate"),
    ("cv a=1 medium r64", "medium", 64, 1.0),
]


def settings(quick: bool) -> dict:
    """Problem size; tests monkeypatch this to shrink the run."""
    if quick:
        return {"scenes": ["garage", "dynamics"], "width": 96, "height": 72,
                "reference_spp": 2048, "spp": [4, 16, 64], "configs": CV_CONFIGS}
    return {"scenes": ["garage", "dynamics", "garden"], "width": 256, "height": 192,
            "reference_spp": 4096, "spp": [4, 8, 16, 32, 64, 128, 256],
            "configs": CV_CONFIGS}


def points(s: dict, seed: int) -> list[dict]:
    """The sweep's points (``vc.experiments.sweep``): per scene, product and every cv
    configuration at every spp of the ladder, in the order of the tables."""
    out = []
    common = {"width": s["width"], "height": s["height"], "seed": seed,
              "reference": {"method": "product", "spp": s["reference_spp"],
                            "seed": seed + 104729}}
    for name in s["scenes"]:
        out += [{**common, "scene": name, "method": "product", "spp": spp, "label": "product"}
                for spp in s["spp"]]
        for label, preset, resolution, alpha in s["configs"]:
            # One cache per (preset, resolution): the sweep builds it once and both alphas
            # share it.
            cache = {"preset": preset, "nearest_hits": False, "seed": seed}
            if resolution is not None:
                cache["resolution"] = resolution
            out += [{**common, "scene": name, "method": "cv", "spp": spp, "label": label,
                     "params": {"alpha": alpha}, "cache": cache} for spp in s["spp"]]
    return out


def run(ctx) -> None:
    s = settings(ctx.quick)
    ctx.record("settings", {**s, "configs": [list(c) for c in s["configs"]]})
    ladder = s["spp"]
    plt = pyplot()
    summary = {}
    table = ctx.sweep(points(s, ctx.seed))
    for name in s["scenes"]:
        scene_rows = table[table["scene"] == name].to_dict("records")
        first = scene_rows[0]
        ref_spp, ref_seconds = first["reference_spp"], first["reference_seconds"]
        ref_var = first["reference_variance"]
        ctx.record(f"{name}/reference", {"spp": ref_spp, "seconds": ref_seconds,
                                         "variance": ref_var})
        resolutions = {c[0]: (c[1], c[2]) for c in s["configs"]}
        rows = []
        for r in scene_rows:
            if r["method"] == "cv":
                preset, resolution = resolutions[r["label"]]
                key = f"{name}/cache/{preset}/{resolution}"
                if key not in ctx.results:
                    ctx.record(key, {
                        "records": r["records"], "shadow_rays": r["cache_shadow_rays"],
                        "shadow_rays_per_pixel": r["cache_rays_per_pixel"],
                        "seconds": r["cache_seconds"],
                        "memory_bytes": r["cache_memory_bytes"]})
            rows.append({"config": r["label"], "spp": r["spp"],
                         "render_seconds": r["render_seconds"],
                         "cache_seconds": r["cache_seconds"],
                         "total_seconds": r["total_seconds"], "mse_raw": r["relmse_raw"],
                         "mse": r["relmse"],
                         "mse_rgb": [r["relmse_r"], r["relmse_g"], r["relmse_b"]],
                         "variance": r["variance"], "efficiency": r["efficiency"],
                         "efficiency_total": r["efficiency_total"], "records": r["records"]})
        ctx.record(f"{name}/rows", rows)
        width, height = s["width"], s["height"]

        by_config: dict[str, list[dict]] = {}
        for r in rows:
            by_config.setdefault(r["config"], []).append(r)
        top = {c: rs[-1] for c, rs in by_config.items()}
        prod = top["product"]
        summary[name] = {
            c: {"spp": r["spp"], "mse_ratio_to_product": r["mse"] / prod["mse"],
                "efficiency_gain": r["efficiency"] / prod["efficiency"],
                "efficiency_gain_total": r["efficiency_total"] / prod["efficiency_total"]}
            for c, r in top.items()
        }
        ctx.record(f"{name}/summary", summary[name])

        ctx.note(f"### {name}\n\n{width}x{height}; reference: product, "
                 f"{ref_spp} spp, {ref_seconds:.3g} s, its own "
                 f"variance share {ref_var:.4g} (subtracted from every relMSE).")
        ctx.table(
            f"{name}: error against time",
            ["config", "spp", "records", "render s", "cache s", "total s", "relMSE",
             "relMSE R/G/B", "relMSE (raw)", "reported var", "eff 1/(relMSE s)",
             "eff (total)"],
            [[r["config"], r["spp"], r["records"], r["render_seconds"], r["cache_seconds"],
              r["total_seconds"], r["mse"], " / ".join(f"{v:.3g}" for v in r["mse_rgb"]),
              r["mse_raw"], r["variance"], r["efficiency"], r["efficiency_total"]]
             for r in rows],
        )
        ctx.table(
            f"{name}: at {ladder[-1]} spp, relative to product",
            ["config", "relMSE / product's", "efficiency gain", "efficiency gain (total)"],
            [[c, v["mse_ratio_to_product"], v["efficiency_gain"], v["efficiency_gain_total"]]
             for c, v in summary[name].items()],
        )

        fig, (a0, a1, b) = plt.subplots(1, 3, figsize=(17, 4.8))
        for c, rs in by_config.items():
            style = ("k-o" if c == "product" else "r-*" if c.startswith("cv auto")
                     else ("--s" if "a=est" in c else "-o"))
            m = [max(r["mse"], 1e-300) for r in rs]
            a0.loglog([r["render_seconds"] for r in rs], m, style, label=c, ms=4)
            a1.loglog([r["total_seconds"] for r in rs], m, style, label=c, ms=4)
        for ax, what in ((a0, "render"), (a1, "render + cache build")):
            ax.set_xlabel(f"seconds ({what})")
            ax.set_ylabel("relMSE (RGB)")
            ax.set_title(f"{name}: relMSE against {what} time")
            ax.legend(fontsize=7)
        labels = list(top)
        x = np.arange(len(labels))
        b.bar(x - 0.2, [top[c]["efficiency"] for c in labels], 0.4, label="render only")
        b.bar(x + 0.2, [top[c]["efficiency_total"] for c in labels], 0.4,
              label="with cache build")
        b.set_xticks(x, labels, rotation=35, ha="right", fontsize=8)
        b.set_ylabel("efficiency 1/(relMSE s)")
        b.set_title(f"{name}: efficiency at {ladder[-1]} spp")
        b.legend(fontsize=8)
        fig.tight_layout()
        ctx.figure(f"tradeoff_{name}", fig)
    ctx.record("summary", summary)
