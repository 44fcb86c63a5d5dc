"""``proxies``: probabilistic visibility with geometry proxies (BLD, Billen, Lagae and
Dutré; issue 66 §5), Tables 4-6 and Fig. 5-8 analogues, against exact visibility.

Per scene (quick: cornell ``dense_blocks`` at 64x48; full: cornell ``dense_blocks``
(blocks of 81,920 triangles each), garden (foliage: the paper's nature and forest),
hairball (its convex hull: the paper's 32-triangle proxy) and blob (one closed dense mesh:
inside proxies), at 128x96) the proxy sets of each kind the scene allows are built for its
dense objects (those holding at least 1% of its triangles): boxes and convex hulls
(outside), inscribed spheres (inside, watertight objects only), vertex clustering
(general). Their triangle counts and build seconds are Table 4's.

Renders: ``method="env"`` (the map's distribution and a point on each area light, exact
shadow rays) and ``method="stochastic"`` with the same samples and eq. 8's estimate of
each shadow ray's visibility, for every proxy set and ``probabilities`` "equal",
"optimal" and "cost" (16 probe rays per pixel). Equal time: every render first takes
``base_spp`` samples per pixel; the fastest sets the budget every render is then given
(a half, one and two times it). Per render: relMSE on RGB against ``"env"`` at
``reference_spp`` with another seed (its variance subtracted), efficiency 1 / (relMSE s),
shadow rays, proxy and scene rays, node visits and triangle tests per pixel (Table 5's
rows). Outputs:
results.json, results.md, relMSE-vs-seconds plots, images.

Targets (issue 66 §6): efficiency >= 1.0x exact visibility on hairball and garden with the
best mode; a proxy build for a 1M-triangle scene <= 2 s (``cargo bench --bench
proxies``); the stochastic shadow ray <= 1.1x an exact one where it tests the scene.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

import viscache_rs as vc

from ._context import ExperimentContext, pyplot

DESCRIPTION = __doc__

#: Target of issue 66 §6: efficiency over exact visibility with the best mode.
TARGET_EFFICIENCY = 1.0

#: Probability modes, in the order of the tables.
MODES = ("equal", "optimal", "cost")

#: Proxy sets: label, ``Proxies.build`` keywords, whether it needs watertight objects.
KINDS: list[tuple[str, dict[str, Any], bool]] = [
    ("boxes", {"kind": "outside"}, False),
    ("hull", {"kind": "outside", "hull": True, "target": 32}, False),
    ("spheres", {"kind": "inside", "spheres": 40}, True),
    ("clusters", {"kind": "general"}, False),
]


def settings(quick: bool) -> dict[str, Any]:
    """Problem size; tests monkeypatch this to shrink the run."""
    if quick:
        return {"scenes": [("cornell", "dense_blocks", ("boxes", "spheres"))],
                "width": 64, "height": 48, "base_spp": 64, "reference_spp": 1024,
                "budgets": [1.0], "modes": ("equal", "optimal")}
    return {"scenes": [("cornell", "dense_blocks", ("boxes", "hull", "spheres", "clusters")),
                       ("garden", None, ("boxes", "hull", "clusters")),
                       ("hairball", None, ("boxes", "hull", "clusters")),
                       ("blob", None, ("boxes", "hull", "spheres", "clusters"))],
            "width": 128, "height": 96, "base_spp": 64, "reference_spp": 2048,
            "budgets": [0.5, 1.0, 2.0], "modes": MODES}


def dense_objects(scene, share: float = 0.01) -> list[int]:
    """Ids of the objects holding at least ``share`` of the scene's triangles."""
    ids = np.asarray(scene.object_ids())
    counts = np.bincount(ids, minlength=len(scene.object_names()))
    return [int(i) for i in np.flatnonzero(counts >= share * len(ids))]


def per_pixel(stats: dict[str, Any], key: str, pixels: int) -> float:
    return float(stats.get(key, 0)) / pixels


def run(ctx: ExperimentContext) -> None:
    s = settings(ctx.quick)
    ctx.record("settings", s)
    plt = pyplot()
    kw: dict[str, Any] = {"threads": ctx.threads, "progress": ctx.progress,
                          "seed": ctx.seed}
    summary: dict[str, Any] = {}
    pixels = s["width"] * s["height"]
    for name, variant, kinds in s["scenes"]:
        label = name if variant is None else f"{name}-{variant}"
        setup = vc.scenes.load(name, variant=variant)
        cam = setup.camera.with_resolution(s["width"], s["height"])
        objects = dense_objects(setup.scene)

        def render(method, _setup=setup, _cam=cam, **params):
            return vc.render(_setup, camera=_cam, method=method, **params, **kw)

        # The reference draws its own light samples (another seed): one sharing the
        # compared renders' samples would hide their error.
        ref = vc.render(setup, camera=cam, method="env", spp=s["reference_spp"],
                        threads=ctx.threads, progress=ctx.progress, seed=ctx.seed + 7919)
        ref_image = np.asarray(ref.image, np.float64)
        ref_var = np.asarray(ref.variance, np.float64)
        exposure = 0.5 / max(float(np.percentile(ref_image, 99)), 1e-6)
        ctx.image(f"{label}_reference", ref_image, exposure=exposure)

        # Table 4: the proxy sets, their triangles and build seconds.
        sets: dict[str, Any] = {}
        table4: list[dict[str, Any]] = []
        for kind, params, watertight in KINDS:
            if kind not in kinds:
                continue
            t = time.perf_counter()
            try:
                proxies = vc.Proxies.build(setup.scene, objects=objects, **params)
            except ValueError as e:
                # Inside proxies need watertight objects: say which scene refused and why.
                table4.append({"proxies": kind, "error": str(e)})
                continue
            seconds = time.perf_counter() - t
            sets[kind] = proxies
            table4.append({"proxies": kind, "kind": proxies.kind,
                           "triangles": int(proxies.num_triangles), "seconds": seconds,
                           "watertight_needed": watertight})
        ctx.record(f"{label}/proxies", {"objects": objects,
                                        "object_triangles": int(sum(
                                            np.isin(np.asarray(setup.scene.object_ids()),
                                                    objects))),
                                        "sets": table4})

        columns: list[tuple[str, str, dict[str, Any]]] = [("exact", "env", {})]
        for kind, proxies in sets.items():
            for mode in s["modes"]:
                columns.append((f"{kind}/{mode}", "stochastic",
                                {"proxies": proxies, "probabilities": mode}))

        fixed: list[dict[str, Any]] = []
        for col, method, params in columns:
            res = render(method, spp=s["base_spp"], **params)
            fixed.append({"method": col, "seconds": float(res.stats["seconds"])})
        budget = min(r["seconds"] for r in fixed)

        rows: list[dict[str, Any]] = []
        for factor in s["budgets"]:
            for col, method, params in columns:
                res = render(method, time_budget=factor * budget, **params)
                st = res.stats
                err = vc.metrics.relmse(res.image, ref_image, ref_var)
                row = {"method": col, "budget_factor": factor,
                       "seconds": float(st["seconds"]), "spp": int(st["spp"]),
                       "relmse": err,
                       "efficiency": vc.metrics.efficiency(err, float(st["seconds"]))}
                for key in ("shadow_rays", "proxy_rays", "scene_rays", "probe_rays",
                            "proxy_nodes", "proxy_triangle_tests", "scene_nodes",
                            "scene_triangle_tests"):
                    if key in st:
                        row[f"{key}_per_pixel"] = per_pixel(st, key, pixels)
                rows.append(row)
                if factor == 1.0:
                    tag = col.replace("/", "_")
                    ctx.image(f"{label}_{tag}", res.image, exposure=exposure)
        ctx.record(f"{label}/equal_time", rows)
        equal = {r["method"]: r for r in rows if r["budget_factor"] == 1.0}
        exact = equal["exact"]
        ctx.table(f"{label}: equal time {budget:.3g} s, {len(objects)} dense objects",
                  ["method", "s", "spp", "relMSE", "efficiency / exact",
                   "scene rays / px", "proxy rays / px", "scene tri tests / px"],
                  [[m, r["seconds"], r["spp"], r["relmse"],
                    r["efficiency"] / max(exact["efficiency"], 1e-30),
                    r.get("scene_rays_per_pixel", float("nan")),
                    r.get("proxy_rays_per_pixel", float("nan")),
                    r.get("scene_triangle_tests_per_pixel", float("nan"))]
                   for m, r in equal.items()])
        best = max((r for m, r in equal.items() if m != "exact"),
                   key=lambda r: r["efficiency"], default=None)
        summary[label] = {
            "best": None if best is None else best["method"],
            "best_over_exact": (None if best is None
                                else best["efficiency"] / max(exact["efficiency"], 1e-30)),
        }
        summary[label]["met"] = (summary[label]["best_over_exact"] or 0) >= TARGET_EFFICIENCY
        curve_figure(ctx, plt, label, rows, [c for c, _, _ in columns])
    ctx.record("summary", summary)
    ctx.table("Targets (issue 66 §6): best mode's efficiency over exact visibility (>= 1.0x)",
              ["scene", "best", "efficiency / exact", "met"],
              [[k, v["best"], v["best_over_exact"], v["met"]] for k, v in summary.items()])
    ctx.note("relMSE is on RGB against method \"env\" (exact visibility, the same light "
             "sampling) at many samples, its own variance subtracted. Seconds are "
             "wall-clock on a possibly shared machine; the proxies' build is not in them "
             "(Table 4 gives it).")


def curve_figure(ctx, plt, label, rows, columns) -> None:
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for name in columns:
        mine = sorted((r for r in rows if r["method"] == name), key=lambda r: r["seconds"])
        ax.loglog([r["seconds"] for r in mine], [max(r["relmse"], 1e-9) for r in mine],
                  "o-", ms=3, label=name)
    ax.set_xlabel("seconds")
    ax.set_ylabel("relMSE (RGB) against exact visibility")
    ax.set_title(f"{label}: relMSE against time", fontsize=9)
    ax.legend(fontsize=6)
    ctx.figure(f"{label}_relmse_vs_seconds", fig)
