"""A sweep's tasks, run on a Dask worker or in this process: a scene's reference, a shared
visibility cache, and one point's row.

Every task is a function of its arguments alone (seeds included), so a task lost with its
worker and run again elsewhere gives the same values; only the seconds differ. A worker
keeps the scenes and G-buffers it made (the scenes are procedural: made again, they are
the same triangles, with the same fingerprint), so the points of one scene pay for its
BVH once per worker.
"""

from __future__ import annotations

import functools
import json
import math
import os
import tempfile
from typing import Any

import numpy as np

from .. import metrics, scenes
from ..cache import VisibilityCache
from ..render import render

#: Columns of a row that are times, or figures made of times: a row run twice differs in
#: these alone (for points without a time budget, whose samples depend on the speed).
TIMING_COLUMNS = ("render_seconds", "cache_seconds", "total_seconds", "efficiency",
                  "efficiency_total", "reference_seconds", "stats")


@functools.lru_cache(maxsize=8)
def _setup(scene: str, detail: float, seed: int):
    setup = scenes.load(scene, detail=detail, seed=seed)
    setup.scene.build(threads=1)
    return setup


@functools.lru_cache(maxsize=16)
def _view(scene: str, detail: float, seed: int, width: int, height: int):
    """The setup, camera and G-buffer (first hits through the pixel centres: the cache's
    record points and every render's anchors) of a scene at a size."""
    setup = _setup(scene, detail, seed)
    camera = setup.camera.with_resolution(width, height)
    return setup, camera, setup.scene.gbuffer(camera, jitter=False, threads=1)


def _render(setup, camera, gbuffer, method: str, threads: int, **kw):
    from .. import _core

    row = {m["name"]: m for m in _core.methods()}[method]
    if "gbuffer" in row["params"]:
        kw["gbuffer"] = gbuffer
    else:
        kw["camera"] = camera
    return render(setup, method=method, threads=threads, progress=False, **kw)


def reference(scene: str, detail: float, scene_seed: int, width: int, height: int, method: str,
              spp: int, seed: int, threads: int = 1) -> dict[str, Any]:
    """The reference image of a scene at a size: ``image`` and ``variance`` (of the mean,
    float64, (H, W, 3)), ``seconds``, ``spp``."""
    setup, camera, gbuffer = _view(scene, detail, scene_seed, width, height)
    res = _render(setup, camera, gbuffer, method, threads, spp=spp, seed=seed)
    return {"image": np.asarray(res.image, np.float64),
            "variance": np.asarray(res.variance, np.float64),
            "seconds": float(res.stats["seconds"]), "spp": spp}


def cache(scene: str, detail: float, scene_seed: int, width: int, height: int,
          settings: dict[str, Any], threads: int = 1) -> dict[str, Any]:
    """A visibility cache built at a view's anchors, as the bytes of its file (what crosses
    between workers; the points load it against their own copy of the scene), with its
    build's figures."""
    setup, _camera, gbuffer = _view(scene, detail, scene_seed, width, height)
    kw = dict(settings)
    seed = kw.pop("seed", 0)
    built = VisibilityCache(setup.scene, **kw)
    report = built.build(gbuffer=gbuffer, seed=seed, threads=threads, progress=False)
    with tempfile.TemporaryDirectory(prefix="viscache-sweep-") as folder:
        path = os.path.join(folder, "cache.vcache")
        built.save(path)
        with open(path, "rb") as f:
            data = f.read()
    return {"bytes": data, "records": len(built), "memory_bytes": built.memory_bytes(),
            "seconds": float(report["seconds"]), "shadow_rays": int(report["shadow_rays"]),
            "shadow_rays_per_pixel": float(report["shadow_rays_per_pixel"])}


def _load_cache(setup, shared: dict[str, Any]) -> VisibilityCache:
    with tempfile.TemporaryDirectory(prefix="viscache-sweep-") as folder:
        path = os.path.join(folder, "cache.vcache")
        with open(path, "wb") as f:
            f.write(shared["bytes"])
        return VisibilityCache.load(path, setup.scene)


def _scalars(stats: dict[str, Any]) -> str:
    """The render's figures that are single numbers or words, as JSON."""
    keep = {k: v for k, v in stats.items()
            if isinstance(v, bool | int | str) or isinstance(v, float) and math.isfinite(v)}
    return json.dumps(keep, sort_keys=True)


def _channels(variance: np.ndarray) -> list[float]:
    """Mean per-pixel variance of each channel, finite pixels only
    (``vc.metrics.variance_ratio``'s sums, divided by one count)."""
    v = np.asarray(variance, np.float64).reshape(-1, 3)
    keep = np.isfinite(v)
    return [float(v[keep[:, c], c].mean()) if keep[:, c].any() else math.nan
            for c in range(3)]


def point(p: dict[str, Any], index: int, ref: dict[str, Any] | None,
          shared: dict[str, Any] | None, threads: int = 1) -> dict[str, Any]:
    """One point's row: the render's samples, seconds, variance and, against ``ref``, its
    relMSE on RGB (the reference's own variance share subtracted, ``vc.metrics.relmse``)
    and efficiency 1 / (relMSE s). A value the renderer refuses (an ``alpha`` out of
    range) is raised naming the point, ``points[index]``."""
    try:
        return _point(p, index, ref, shared, threads)
    except (ValueError, TypeError) as e:
        raise type(e)(f"points[{index}] ({p['label']}): {e}") from e


def _point(p: dict[str, Any], index: int, ref: dict[str, Any] | None,
           shared: dict[str, Any] | None, threads: int) -> dict[str, Any]:
    setup, camera, gbuffer = _view(p["scene"], p["detail"], p["scene_seed"], p["width"],
                                   p["height"])
    kw = dict(p["params"])
    if p["spp"] is not None:
        kw["spp"] = p["spp"]
    if p["time_budget"] is not None:
        kw["time_budget"] = p["time_budget"]
    seconds = math.inf
    res = None
    for _ in range(p["repeats"]):
        if shared is not None:
            # A fresh copy per render: a cv render gives its records' misses back to the
            # cache, so a shared cache would make a point depend on the ones before it.
            kw["cache"] = _load_cache(setup, shared)
        res = render_once = _render(setup, camera, gbuffer, p["method"], threads,
                                    seed=p["seed"], **kw)
        seconds = min(seconds, float(render_once.stats["seconds"]))
    assert res is not None
    stats = res.stats
    image = np.asarray(res.image, np.float64)
    variance = np.asarray(res.variance, np.float64)
    build = shared["seconds"] if shared is not None else 0.0
    total = seconds + build
    row: dict[str, Any] = {
        "index": index, "label": p["label"], "scene": p["scene"], "method": p["method"],
        "width": p["width"], "height": p["height"], "detail": p["detail"],
        "scene_seed": p["scene_seed"],
        "seed": p["seed"], "spp_asked": p["spp"] if p["spp"] is not None else -1,
        "time_budget": p["time_budget"] if p["time_budget"] is not None else math.nan,
        "params": json.dumps(p["params"], sort_keys=True),
        "cache": json.dumps(p["cache"], sort_keys=True) if p["cache"] is not None else "",
        "spp": int(stats["spp"]), "mean_spp": float(stats.get("mean_spp", stats["spp"])),
        "render_seconds": seconds, "cache_seconds": build, "total_seconds": total,
        "records": shared["records"] if shared is not None else 0,
        "cache_memory_bytes": shared["memory_bytes"] if shared is not None else 0,
        "cache_shadow_rays": shared["shadow_rays"] if shared is not None else 0,
        "cache_rays_per_pixel": (shared["shadow_rays_per_pixel"] if shared is not None
                                 else 0.0),
        "mean_variance": metrics.mean_variance(variance),
    }
    row.update(zip(("var_r", "var_g", "var_b"), _channels(variance), strict=True))
    if ref is not None:
        r_img, r_var = ref["image"], ref["variance"]
        mse = metrics.relmse(image, r_img, r_var)
        rgb = metrics.relmse_per_channel(image, r_img, r_var)
        row.update({
            "relmse": mse, "relmse_raw": metrics.relmse(image, r_img),
            "relmse_r": float(rgb[0]), "relmse_g": float(rgb[1]), "relmse_b": float(rgb[2]),
            "variance": metrics.relative_variance(variance, r_img),
            "efficiency": metrics.efficiency(mse, seconds),
            "efficiency_total": metrics.efficiency(mse, total),
            "reference_spp": ref["spp"], "reference_seconds": ref["seconds"],
            "reference_variance": metrics.relative_variance(r_var, r_img),
        })
    else:
        row.update({k: math.nan for k in (
            "relmse", "relmse_raw", "relmse_r", "relmse_g", "relmse_b", "variance",
            "efficiency", "efficiency_total", "reference_seconds", "reference_variance")})
        row["reference_spp"] = 0
    row["stats"] = _scalars(stats)
    if p["image"]:
        row["image"] = np.asarray(res.image, np.float32)
    return row
