"""CAM08 Tables 2-3 and Fig. 13: product sampling against product sampling with the cache's
control variate, per scene and sample count.

For garage, dynamics and garden (the paper's three scenes), at 10/30/100/300 samples per
pixel: seconds of product sampling and of the control variate (alpha = 1 as in the paper,
and alpha estimated from neighbouring pixels), the overhead in seconds and percent (render
alone, and with the cache build amortised over one frame), and the variance ratio: the
mean over pixels of the luminance variance of the mean, control variate over product.
Table 2: records, record size and the cache's amortised shadow rays per pixel. Fig. 13: an
equal-time comparison on garage (cv at 30 spp against product at the spp that takes the
same time), with the images side by side.

Both methods shade one point per pixel and draw every sample there (CAM08's setting), with
the same product cells (32^2), seeds and threads; the cache is built once per scene with
the ``medium`` preset at the paper's record resolutions (Table 2: garage and garden 32^2,
dynamics 64^2). ``--quick`` renders 256x192 at 10/30/100 spp; the full mode 640x480 at
10/30/100/300.
"""

from __future__ import annotations

import numpy as np

from .. import scenes
from ..render import render
from ._context import ExperimentContext, pyplot

DESCRIPTION = __doc__

LUM = np.array([0.2126, 0.7152, 0.0722])

#: Record resolution per scene (CAM08 Table 2).
RESOLUTION = {"garage": 32, "dynamics": 64, "garden": 32}


def settings(quick: bool) -> dict:
    """Image size, sample counts and scenes of a run."""
    if quick:
        return {"width": 256, "height": 192, "spp": [10, 30, 100],
                "scenes": ["garage", "dynamics", "garden"], "equal_time_spp": 30}
    return {"width": 640, "height": 480, "spp": [10, 30, 100, 300],
            "scenes": ["garage", "dynamics", "garden"], "equal_time_spp": 30}


def mean_variance(res) -> float:
    """Mean over pixels of the luminance variance of the mean."""
    return float((res.variance @ LUM**2).mean())


def run(ctx: ExperimentContext) -> None:
    from .._core import VisibilityCache

    cfg = settings(ctx.quick)
    ctx.record("settings", cfg)
    table3, table2 = [], []
    per_scene = {}
    for name in cfg["scenes"]:
        setup = scenes.load(name, seed=ctx.seed)
        setup.camera = setup.camera.with_resolution(cfg["width"], cfg["height"])
        setup.scene.build(threads=ctx.threads)
        cache = VisibilityCache(setup.scene, resolution=RESOLUTION[name], preset="medium")
        build = cache.build(setup.camera, seed=ctx.seed, threads=ctx.threads,
                            progress=ctx.progress)
        table2.append([name, build["records"], f"{RESOLUTION[name]}x{RESOLUTION[name]}",
                       round(cache.memory_bytes() / max(build["records"], 1)),
                       build["shadow_rays_per_pixel"], build["seconds"]])
        rows = []
        for spp in cfg["spp"]:
            common = dict(spp=spp, seed=ctx.seed + spp, threads=ctx.threads,
                          progress=ctx.progress)
            prod = render(setup, method="product", **common)
            cv1 = render(setup, method="cv", cache=cache, alpha=1.0, **common)
            cve = render(setup, method="cv", cache=cache, alpha="estimate", **common)
            vp = mean_variance(prod)
            t_p = prod.stats["seconds"]
            row = {"spp": spp, "time_product": t_p, "var_product": vp}
            for key, r in (("cv", cv1), ("cv_est", cve)):
                t = r.stats["seconds"]
                row.update({
                    f"time_{key}": t,
                    f"overhead_{key}_s": t - t_p,
                    f"overhead_{key}_pct": 100 * (t - t_p) / t_p,
                    f"overhead_{key}_with_build_pct": 100 * (t + build["seconds"] - t_p) / t_p,
                    f"var_{key}": mean_variance(r),
                    f"ratio_{key}": mean_variance(r) / vp,
                    f"lookup_s_{key}": r.stats["lookup_seconds"],
                    f"control_s_{key}": r.stats["control_seconds"],
                    f"miss_rate_{key}": r.stats["miss_rate"],
                })
            row["mean_alpha_est"] = cve.stats["mean_alpha"]
            rows.append(row)
            table3.append([name, spp, t_p, row["time_cv"], row["overhead_cv_s"],
                           f"{row['overhead_cv_pct']:.1f}%",
                           f"{row['overhead_cv_with_build_pct']:.1f}%",
                           row["ratio_cv"], row["ratio_cv_est"]])
            if spp == cfg["spp"][0]:
                ctx.image(f"{name}_product_{spp}spp", prod.image)
                ctx.image(f"{name}_cv_{spp}spp", cv1.image)
        per_scene[name] = {"build": build, "rows": rows}
        if name == "garage":
            _equal_time(ctx, setup, cache, rows, cfg["equal_time_spp"])
    ctx.record("scenes", per_scene)
    ctx.table("Table 2: the caches", ["scene", "records", "record size", "bytes/record",
                                      "avg rays/pixel", "build s"], table2)
    ctx.table("Table 3: product vs control variate",
              ["scene", "spp", "time product s", "time cv s", "overhead s", "overhead",
               "overhead incl. build", "variance ratio (alpha=1)",
               "variance ratio (alpha est.)"], table3)
    _plot(ctx, per_scene)


def _equal_time(ctx, setup, cache, rows, cv_spp) -> None:
    """Fig. 13: cv at ``cv_spp`` against product at the spp that takes as long."""
    # Render time is close to a + b * spp; fit it on the ladder's product runs.
    spp = np.array([r["spp"] for r in rows], float)
    tp = np.array([r["time_product"] for r in rows], float)
    b, a = np.polyfit(spp, tp, 1) if len(spp) > 1 else (tp[0] / spp[0], 0.0)
    cv = render(setup, spp=cv_spp, method="cv", cache=cache, seed=ctx.seed + 1000,
                threads=ctx.threads, progress=ctx.progress)
    t_cv = cv.stats["seconds"]
    product_spp = max(1, int(round((t_cv - a) / b)))
    prod = render(setup, spp=product_spp, method="product", seed=ctx.seed + 2000,
                  threads=ctx.threads, progress=ctx.progress)
    ratio = mean_variance(cv) / mean_variance(prod)
    ctx.record("equal_time", {"cv_spp": cv_spp, "cv_seconds": t_cv,
                              "product_spp": product_spp,
                              "product_seconds": prod.stats["seconds"],
                              "variance_ratio": ratio})
    ctx.table("Fig. 13: equal time on garage",
              ["method", "spp", "seconds", "mean variance"],
              [["product", product_spp, prod.stats["seconds"], mean_variance(prod)],
               ["cv", cv_spp, t_cv, mean_variance(cv)]])
    ctx.note(f"Equal-time variance ratio (cv / product): {ratio:.3f}")
    both = np.concatenate([prod.image, np.ones_like(prod.image[:, :4]), cv.image], axis=1)
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
