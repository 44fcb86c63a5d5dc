"""CAM08 sec. 4.1 (Figs. 3-4): how strongly visibility correlates between surface points, as
a function of their distance d and the angle theta between their normals.

Per scene: the first hits of a jittered G-buffer are the points (misses dropped); each gets
its visibility map (``analysis.visibility_maps``, the cache's record pattern); pairs are
each point's nearest neighbours plus partners at log-uniform distances along its tangent
plane, up to the points' bounding-box diagonal (``analysis.sample_pairs``);
``analysis.correlation_bins`` gives rho_bar(d, theta) with standard deviations and pair
counts. Distances are in world units;
the plots span a quarter of each scene's diagonal, and "small d" is 2 % of the diagonal.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from .. import analysis
from ..io import write_exr
from ..scenes import load
from ._context import ExperimentContext, pyplot

DESCRIPTION = (
    "CAM08 sec. 4.1 / Figs. 3-4: average visibility correlation rho_bar(d, theta) between "
    "surface points by distance and normal difference, per scene (garage, dynamics, "
    "garden): heatmaps, Fig. 3 curves with +-sigma, pair counts, and the Fig. 4 per-pixel "
    "local correlation."
)

SCENES = ("garage", "dynamics", "garden")


@dataclass(frozen=True)
class Settings:
    """How hard one scene is measured."""

    width: int  # G-buffer size: one point per pixel hit
    height: int
    resolution: int  # visibility map side R (R*R directions)
    neighbours: int  # nearest-neighbour partners per point
    far: int  # log-distance partners per point
    d_bins: int = 50  # distance bins over [0, d_span * diagonal]
    d_span: float = 0.25
    theta_step: float = 2.0  # degrees per angle bin over [0, 180]
    d_small: float = 0.02  # "small d" of Fig. 3 and the summary, times the diagonal
    theta_local: float = 10.0  # Fig. 4's theta_max, degrees (d_max = d_small)
    min_pairs: int = 20  # bins with fewer pairs are left white


QUICK = Settings(width=192, height=144, resolution=32, neighbours=32, far=64)
FULL = Settings(width=320, height=240, resolution=64, neighbours=64, far=128)


def _cell(b: dict, i: int = 0, j: int = 0) -> dict:
    return {"mean": float(b["mean"][i, j]), "std": float(b["std"][i, j]),
            "count": int(b["count"][i, j]), "undefined": int(b["undefined"][i, j])}


def measure(setup, s: Settings, seed: int, threads: int | None, progress: bool | None) -> dict:
    """Every figure of one scene (see the module docs)."""
    t0 = time.perf_counter()
    cam = setup.camera.with_resolution(s.width, s.height)
    g = setup.scene.gbuffer(cam, seed=seed, threads=threads)
    hit = np.isfinite(g["depth"]).ravel()
    points = g["position"].reshape(-1, 3)[hit]
    normals = g["normal"].reshape(-1, 3)[hit]
    maps = analysis.visibility_maps(setup.scene, points, normals, resolution=s.resolution,
                                    threads=threads, progress=progress)
    t_maps = time.perf_counter() - t0
    diag = float(np.linalg.norm(points.max(0) - points.min(0)))
    d_edges = np.linspace(0.0, s.d_span * diag, s.d_bins + 1)
    theta_edges = np.arange(0.0, 180.0 + s.theta_step / 2, s.theta_step)
    d_small = s.d_small * diag
    pairs = analysis.sample_pairs(maps, neighbours=s.neighbours, far=s.far,
                                  far_range=(d_edges[1] / 4, diag), seed=seed,
                                  threads=threads)

    def bins(de, te):
        return analysis.correlation_bins(maps, de, te, pairs=pairs, threads=threads)

    heat = bins(d_edges, theta_edges)
    vs_theta = bins([0.0, d_small], theta_edges)  # Fig. 3 left: d < small
    vs_d = bins(d_edges, [0.0, 2.0])  # Fig. 3 right: theta < 2 degrees
    summary = bins([0.0, d_small, s.d_span * diag, 2.0 * diag], [0.0, 2.0, 10.0, 45.0, 180.0])
    local = analysis.local_correlation(maps, d_small, s.theta_local, threads=threads)
    image = np.full(hit.shape, np.nan)
    image[hit] = local["mean"]
    vis = maps.visible_fraction()
    return {
        "points": len(points),
        "pairs": int(heat["pairs"]),
        "pairs_undefined": int(heat["undefined"].sum()),
        "pairs_outside": int(heat["outside"]),
        "constant_maps": int(np.count_nonzero((vis == 0) | (vis == 1))),
        "mean_visible_fraction": float(vis.mean()),
        "diagonal": diag,
        "d_small": d_small,
        "seconds_maps": t_maps,
        "seconds": time.perf_counter() - t0,
        "heatmap": {k: heat[k] for k in
                    ("distance_edges", "theta_edges", "count", "mean", "std", "undefined")},
        "vs_theta_small_d": {k: vs_theta[k] for k in ("theta_edges", "count", "mean", "std")},
        "vs_d_small_theta": {k: vs_d[k] for k in ("distance_edges", "count", "mean", "std")},
        "summary": {
            "small_d_theta_lt_2": _cell(summary, 0, 0),
            "small_d_theta_2_10": _cell(summary, 0, 1),
            "small_d_theta_10_45": _cell(summary, 0, 2),
            "small_d_theta_45_180": _cell(summary, 0, 3),
            "mid_d_theta_lt_2": _cell(summary, 1, 0),
            "far_d_theta_lt_2": _cell(summary, 2, 0),
        },
        "local": {"d_max": d_small, "theta_max_deg": s.theta_local,
                  "image": image.reshape(s.height, s.width),
                  "mean": float(np.nanmean(local["mean"])),
                  "partners_median": float(np.median(local["count"]))},
    }


def _plot(ctx: ExperimentContext, name: str, r: dict, s: Settings) -> None:
    plt = pyplot()
    h = r["heatmap"]
    mean = np.clip(np.asarray(h["mean"], float), 0.0, 1.0)
    mean[np.asarray(h["count"]) < s.min_pairs] = np.nan
    de, te = h["distance_edges"], h["theta_edges"]
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
    cmap = plt.get_cmap("jet").with_extremes(bad="white")
    im = ax[0].imshow(mean.T, origin="upper", aspect="auto", cmap=cmap, vmin=0, vmax=1,
                      extent=(de[0], de[-1], te[-1], te[0]), interpolation="nearest")
    ax[0].add_patch(plt.Rectangle((0, 0), r["d_small"], r["local"]["theta_max_deg"],
                                  fill=False, ec="k", lw=1.2))
    ax[0].set(xlabel="d (world units)", ylabel="theta (degrees)",
              title=f"{name}: rho_bar(d, theta), clamped to [0, 1]")
    fig.colorbar(im, ax=ax[0])
    for a, curve, edges, label, title in (
        (ax[1], r["vs_theta_small_d"], "theta_edges", "theta (degrees)",
         f"d < {r['d_small']:.3g}"),
        (ax[2], r["vs_d_small_theta"], "distance_edges", "d (world units)", "theta < 2 deg"),
    ):
        e = np.asarray(curve[edges], float)
        x = 0.5 * (e[:-1] + e[1:])
        m = np.asarray(curve["mean"], float).ravel()
        sd = np.asarray(curve["std"], float).ravel()
        ok = np.asarray(curve["count"]).ravel() >= s.min_pairs
        a.plot(x[ok], m[ok], "k-", label="mean")
        a.plot(x[ok], (m + sd)[ok], "k--", lw=0.8, label="+-sigma")
        a.plot(x[ok], (m - sd)[ok], "k--", lw=0.8)
        a.set(xlabel=label, ylabel="rho", ylim=(-0.2, 1.05), title=f"{name}: {title}")
        a.grid(alpha=0.3)
        a.legend(loc="lower left")
    ctx.figure(f"{name}_correlation", fig)

    fig, a = plt.subplots(figsize=(6, 4.5))
    img = np.clip(r["local"]["image"], 0.0, 1.0)
    im = a.imshow(np.ma.masked_invalid(img), cmap=cmap, vmin=0, vmax=1)
    a.set_axis_off()
    a.set_title(f"{name}: mean rho to points within\n"
                f"d < {r['d_small']:.3g}, "
                f"theta < {r['local']['theta_max_deg']:g} deg")
    fig.colorbar(im, ax=a)
    ctx.figure(f"{name}_local", fig)


def run(ctx: ExperimentContext, scenes=SCENES, settings: Settings | None = None) -> None:
    s = settings or (QUICK if ctx.quick else FULL)
    ctx.record("settings", asdict(s))
    rows, marg = [], []
    for name in scenes:
        if ctx.progress is not False:  # a line per scene, bar or not
            print(f"correlation: {name} ({s.width}x{s.height} points, "
                  f"{s.resolution}x{s.resolution} maps)", flush=True)
        r = measure(load(name), s, ctx.seed, ctx.threads, ctx.progress)
        _plot(ctx, name, r, s)
        # The per-pixel image goes to an EXR (NaN where the pixel missed or had no
        # partner), not into results.json.
        image = r["local"].pop("image")
        write_exr(ctx.out / f"{name}_local.exr",
                  np.repeat(image[..., None], 3, axis=2).astype(np.float32))
        r["local"]["exr"] = f"{name}_local.exr"
        ctx.record(name, r)
        sm = r["summary"]
        c = sm["small_d_theta_lt_2"]
        rows.append([name, r["points"], r["pairs"], r["pairs_undefined"],
                     f"{r['d_small']:.3g}", f"{c['mean']:.3f} ± {c['std']:.3f}", c["count"],
                     f"{sm['small_d_theta_2_10']['mean']:.3f}",
                     f"{sm['small_d_theta_45_180']['mean']:.3f}",
                     f"{sm['mid_d_theta_lt_2']['mean']:.3f}",
                     f"{r['local']['mean']:.3f}", f"{r['seconds']:.1f}"])
        vt, vd = r["vs_theta_small_d"], r["vs_d_small_theta"]
        te, de = np.asarray(vt["theta_edges"]), np.asarray(vd["distance_edges"])
        for k in (0, 5, 15, 30, 45, 60, 89):
            if k < len(te) - 1:
                marg.append([name, "d < small", f"theta {te[k]:g}-{te[k + 1]:g}",
                             float(vt["mean"][0, k]), float(vt["std"][0, k]),
                             int(vt["count"][0, k])])
        nd = len(de) - 1
        for k in sorted({0, 1, nd // 10, nd // 5, nd // 2, nd - 1}):
            marg.append([name, "theta < 2", f"d {de[k]:.3g}-{de[k + 1]:.3g}",
                         float(vd["mean"][k, 0]), float(vd["std"][k, 0]),
                         int(vd["count"][k, 0])])
    ctx.table(
        "Visibility correlation per scene (rho over the whole sphere; small d = 2 % of the "
        "points' bounding-box diagonal)",
        ["scene", "points", "pairs", "undefined pairs", "small d", "rho d<small θ<2°",
         "pairs there", "θ 2-10°", "θ 45-180°", "d small-¼diag θ<2°", "Fig. 4 mean", "s"],
        rows,
    )
    ctx.table("Fig. 3 marginals: mean rho ± sigma", ["scene", "slice", "bin", "mean rho",
                                                     "sigma", "pairs"], marg)
    ctx.note(
        f"Points: first hits of a {s.width}x{s.height} jittered G-buffer; maps "
        f"{s.resolution}x{s.resolution} over the sphere (CAM08 used ~700k points and 96x96); "
        f"pairs: {s.neighbours} nearest neighbours + {s.far} log-distance partners per point. "
        "Bin means average the drawn pairs (nearby pairs are drawn preferentially, as the "
        "paper does to fill the small-d bins). Heatmaps clamp rho to [0, 1] like Fig. 4 and "
        f"leave bins with fewer than {s.min_pairs} pairs white; the box marks Fig. 4's "
        "(d_max, theta_max) neighbourhood."
    )
