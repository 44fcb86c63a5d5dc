"""Reuse of the visibility cache over the frames of an animation (CAM08 sec. 5.3)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from .. import metrics, scenes
from ..cache import VisibilityCache
from ..io import auto_exposure
from ..render import render
from ._context import pyplot

DESCRIPTION = """\
N frames of the animated scene with and without reuse: records inserted and evicted per \
frame, rays per pixel, variance per frame.

The animated ``dynamics`` scene (the sphere rolls 2 m and back every 60 frames) is rendered
with the control variate (method "cv", alpha = 1) in two ways, at the same spp and seed:

- with reuse: one cache carried over the frames (CAM08 sec. 5.3). Per frame: move the
  sphere; ``cache.validate(rays_per_record)`` re-traces a few of every record's directions
  (catches records the motion changed before they are used); ``cache.end_frame()`` evicts
  records whose miss rate (this validation plus the previous frame's render) exceeds
  epsilon_max, and records unused for ``unused_frames`` frames; ``cache.build(camera)``
  refills the cache for the new frame; then the render, which reports its records' misses
  back into the cache for the next frame's eviction.
- fresh: a new cache built for every frame.

Product importance sampling (no cache) at the same spp is the baseline. Per frame it records
the cache's records, inserted and evicted records, the cache's shadow rays per pixel
(build plus validation), render and cache seconds, and the mean over pixels and RGB
channels of the per-pixel variance of each image (``vc.metrics.mean_variance``), and its
ratio to product's per channel (``vc.metrics.variance_ratio``) and on average. Quick: 8
frames (every 4th, 0..28), 128x96, 8 spp; full: 60 frames, 320x240, 16 spp.
"""

def settings(quick: bool) -> dict:
    """Problem size; tests monkeypatch this to shrink the run."""
    if quick:
        return {"frames": list(range(0, 29, 4)), "width": 128, "height": 96, "spp": 8,
                "preset": "medium", "resolution": 32, "validate_rays": 16}
    return {"frames": list(range(60)), "width": 320, "height": 240, "spp": 16,
            "preset": "medium", "resolution": 32, "validate_rays": 16}


def run(ctx) -> None:
    s = settings(ctx.quick)
    setup = scenes.load("dynamics", animated=True)
    cam = setup.camera.with_resolution(s["width"], s["height"])
    pixels = cam.width * cam.height
    spp = s["spp"]
    # CAM08's setting: every sample at the pixel's centre hit, plain product sampling.
    kw: dict[str, Any] = {"threads": ctx.threads, "progress": ctx.progress}
    fixed: dict[str, Any] = {"jitter": False, "technique_weights": {"product": 1}}
    cache_kw = {"resolution": s["resolution"], "preset": s["preset"], "nearest_hits": False}
    ctx.record("settings", s)

    reuse = VisibilityCache(setup.scene, **cache_kw)
    rows: list[dict] = []
    first = last = None
    for i, frame in enumerate(s["frames"]):
        setup.at_frame(frame)
        seed = ctx.seed + frame
        row: dict = {"frame": frame}

        # With reuse: validate, evict, refill, render.
        t = time.perf_counter()
        check = (reuse.validate(rays_per_record=s["validate_rays"], seed=seed,
                                threads=ctx.threads)
                 if s["validate_rays"] and len(reuse) else {"rays": 0, "misses": 0})
        evicted = reuse.end_frame()
        # One G-buffer per frame: the records' points and every render's anchors.
        gbuffer = setup.scene.gbuffer(cam, jitter=False, threads=ctx.threads)
        report = reuse.build(gbuffer=gbuffer, seed=seed, **kw)
        row["reuse_cache_seconds"] = time.perf_counter() - t
        row["records"] = len(reuse)
        row["inserted"] = report["bootstrap_records"] + report["refined_records"]
        row["evicted_by_misses"] = evicted["by_misses"]
        row["evicted_unused"] = evicted["unused"]
        row["validate_rays"] = check["rays"]
        row["validate_misses"] = check["misses"]
        row["reuse_rays_per_pixel"] = (report["shadow_rays"] + check["rays"]) / pixels
        res = render(setup, gbuffer=gbuffer, spp=spp, method="cv", cache=reuse, seed=seed, **kw,
                     **fixed)
        row["reuse_render_seconds"] = res.stats["seconds"]
        row["reuse_variance"] = metrics.mean_variance(res.variance)
        reuse_var = res.variance
        row["reuse_miss_rate"] = res.stats["miss_rate"]
        if i == 0:
            first = res.image
        last = res.image

        # Fresh cache every frame.
        fresh = VisibilityCache(setup.scene, **cache_kw)
        t = time.perf_counter()
        report = fresh.build(gbuffer=gbuffer, seed=seed, **kw)
        row["fresh_cache_seconds"] = time.perf_counter() - t
        row["fresh_records"] = len(fresh)
        row["fresh_rays_per_pixel"] = report["shadow_rays"] / pixels
        res = render(setup, gbuffer=gbuffer, spp=spp, method="cv", cache=fresh, seed=seed, **kw,
                     **fixed)
        row["fresh_render_seconds"] = res.stats["seconds"]
        row["fresh_variance"] = metrics.mean_variance(res.variance)
        fresh_var = res.variance
        del fresh

        res = render(setup, gbuffer=gbuffer, spp=spp, method="product", seed=seed, **kw,
                     **fixed)
        row["product_render_seconds"] = res.stats["seconds"]
        row["product_variance"] = metrics.mean_variance(res.variance)
        rgb, row["reuse_ratio"] = metrics.variance_ratio(reuse_var, res.variance)
        row["reuse_ratio_rgb"] = rgb.tolist()
        rgb, row["fresh_ratio"] = metrics.variance_ratio(fresh_var, res.variance)
        row["fresh_ratio_rgb"] = rgb.tolist()
        rows.append(row)

    ctx.record("frames", rows)
    later = rows[1:] or rows
    summary = {
        "frames": len(rows),
        "mean_reuse_rays_per_pixel_after_first": float(
            np.mean([r["reuse_rays_per_pixel"] for r in later])),
        "mean_fresh_rays_per_pixel": float(np.mean([r["fresh_rays_per_pixel"] for r in rows])),
        "mean_reuse_ratio": float(np.mean([r["reuse_ratio"] for r in rows])),
        "mean_fresh_ratio": float(np.mean([r["fresh_ratio"] for r in rows])),
        "total_inserted_after_first": int(sum(r["inserted"] for r in later)),
        "total_evicted_by_misses": int(sum(r["evicted_by_misses"] for r in rows)),
        "total_evicted_unused": int(sum(r["evicted_unused"] for r in rows)),
        "reuse_cache_seconds": float(sum(r["reuse_cache_seconds"] for r in rows)),
        "fresh_cache_seconds": float(sum(r["fresh_cache_seconds"] for r in rows)),
    }
    ctx.record("summary", summary)

    ctx.note(f"Animated dynamics, {cam.width}x{cam.height}, {spp} spp, frames "
             f"{s['frames'][0]}..{s['frames'][-1]} ({len(rows)}), cache preset "
             f"{s['preset']!r} at {s['resolution']}^2; validation with "
             f"{s['validate_rays']} rays per record before each end_frame. Variance: mean "
             "per-pixel variance over pixels and RGB channels; ratio: to product sampling at "
             "the same spp and seed, the mean of the three channels' ratios (per channel in "
             "results.json). Cache rays per pixel: shadow rays of the "
             "build (reuse: refill plus validation) over the pixels.")
    ctx.table(
        "Per frame",
        ["frame", "records", "inserted", "evicted (misses)", "evicted (unused)",
         "rays/px reuse", "rays/px fresh", "cache s reuse", "cache s fresh",
         "render s reuse", "render s fresh", "render s product",
         "var reuse", "var fresh", "var product", "ratio reuse", "ratio fresh"],
        [[r["frame"], r["records"], r["inserted"], r["evicted_by_misses"], r["evicted_unused"],
          r["reuse_rays_per_pixel"], r["fresh_rays_per_pixel"], r["reuse_cache_seconds"],
          r["fresh_cache_seconds"], r["reuse_render_seconds"], r["fresh_render_seconds"],
          r["product_render_seconds"], r["reuse_variance"], r["fresh_variance"],
          r["product_variance"], r["reuse_ratio"], r["fresh_ratio"]] for r in rows],
    )
    ctx.table("Summary", ["figure", "value"], [[k, v] for k, v in summary.items()])

    plt = pyplot()
    x = [r["frame"] for r in rows]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    a.plot(x, [r["reuse_rays_per_pixel"] for r in rows], "o-", label="with reuse")
    a.plot(x, [r["fresh_rays_per_pixel"] for r in rows], "s--", label="fresh cache")
    a.set_xlabel("frame")
    a.set_ylabel("cache shadow rays per pixel")
    a.set_ylim(bottom=0)
    a.legend()
    b.plot(x, [r["reuse_ratio"] for r in rows], "o-", label="cv, with reuse")
    b.plot(x, [r["fresh_ratio"] for r in rows], "s--", label="cv, fresh cache")
    b.axhline(1.0, color="grey", lw=0.8)
    b.set_xlabel("frame")
    b.set_ylabel("variance / product's")
    b.set_ylim(bottom=0)
    b.legend()
    fig.suptitle(f"Animated dynamics, {cam.width}x{cam.height}, {spp} spp")
    fig.tight_layout()
    ctx.figure("animation", fig)
    assert first is not None and last is not None  # every run renders frames
    exposure = auto_exposure(first)
    ctx.image(f"frame{s['frames'][0]:03d}_reuse", first, exposure)
    ctx.image(f"frame{s['frames'][-1]:03d}_reuse", last, exposure)
