"""Behaviour hashes: SHA-256 of every answer the renderer gives on the suite, to prove that a
refactor of the Rust renderer changes none of them.

A refactor that only restructures code (the "pass layer" of the renderer) must leave every
result bit-identical at a fixed seed. This script computes, on every built-in scene
(``vc.scenes.names()``) at 48x36, a SHA-256 per item (an array's dtype, shape and bytes,
or a stats dict as canonical JSON) of:

- renders (``vc.render``) of every method: "env", "bsdf", "mis", "product" (also at 5 spp,
  with ``light_samples``, product-only weights and a given G-buffer), "cv" (a "medium"
  and an "auto" cache built for the view, and ``cache=None`` where the render builds its
  own, at 16 and 64 spp; ``alpha="estimate"``, ``insert_missing``), "path"
  (``bounces=1``, and ``direct=False``), "vpl" and "vpl_sampled" (over a small VPL set
  traced once per scene), each with ``jitter=True`` and ``jitter=False``, and
  ``adaptive=True`` at 16 spp (deterministic without a time budget): image, variance,
  alpha, sample_counts and stats;
- the G-buffer and the VPL set the renders use;
- cache builds (presets "auto", "medium", "low"): the build report, the parameters,
  ``records()``, the bytes of a saved cache file, ``stats()``; and the records after a cv
  render (which writes the records' misses back);
- ambient occlusion (``vc.render_ao``) from a cache and ray-traced;
- the lighting preview: ``vc.preview`` and ``LightingPreview`` with its transfer prepared
  in the "auto", a budgeted "haar" and the "sh" basis (the prepare report, renders at 0
  and 90 degrees, ``last_bright``);
- the relighter (``vc.Relighter``, pixel visibility and cache visibility): every array
  and the stats of its renders, also after a map rotation, a material edit and at
  threshold 0 (with and without reuse);
- the scene's variants for indirect light and its animated variant at frame 10.

Nothing here uses a time budget (its answer depends on the machine's speed). Excluded from
every stats dict, as timing-dependent (``TIMING_KEYS``): any key containing ``second``
(``seconds``, ``cache_seconds``, ``build_seconds``, ``first_pass_seconds``, the per-stage
``*_seconds``, ``direct_seconds``, ``gather_seconds``, ``vpl_trace_seconds``,
``rays_per_second``, ``samples_per_second``, ``shadow_rays_per_second``), and
``probe_cost_ratio`` (CPU time; None without a budget anyway). Counts (spp, samples,
rays, records, passes, ...) and the ratios that are functions of the samples stay in.

The item names carry no thread count: the results are documented to be bit-identical for
any ``threads``, so ``--threads 1`` and ``--threads 2`` runs may be compared too.

    python benches/behaviour_hashes.py --out before.json [--scenes cornell garage] [--threads 2]
    python benches/behaviour_hashes.py --compare before.json after.json   # exit 1 on a change
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

WIDTH, HEIGHT = 48, 36
SPP = 16  # samples per pixel of the renders: a whole packet of 16 jittered primary rays
ODD_SPP = 5  # and a partial packet
CV_SPP = 64  # "cv" without a cache: at 16 spp its coherence check keeps no records
ADAPTIVE_SPP = 16
VPL_COUNT = 256
VPL_SPP = 4

#: Substrings of stats keys whose values are timings (or CPU-time ratios): left out.
TIMING_KEYS = ("second", "probe_cost_ratio")


def is_timing(key: str) -> bool:
    """A stats key whose value depends on the machine's speed or load."""
    return any(part in key for part in TIMING_KEYS)


def deterministic(value: Any) -> Any:
    """``value`` (a stats dict, possibly nested) without its timing keys, as plain JSON
    types (arrays as nested lists, tuples as lists)."""
    if isinstance(value, dict):
        return {str(k): deterministic(v) for k, v in value.items() if not is_timing(str(k))}
    if isinstance(value, list | tuple):
        return [deterministic(v) for v in value]
    if isinstance(value, np.ndarray):
        return deterministic(value.tolist())
    if isinstance(value, np.generic):
        return deterministic(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)  # nan, inf: JSON has no such numbers
    return value


def hash_array(a: np.ndarray) -> str:
    """SHA-256 of an array's dtype, shape and C-order bytes."""
    a = np.ascontiguousarray(a)
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()


def hash_stats(stats: dict[str, Any]) -> str:
    """SHA-256 of a stats dict's deterministic part as canonical JSON (floats by repr)."""
    text = json.dumps(deterministic(stats), sort_keys=True, allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


class Hashes:
    """The items hashed so far, by name."""

    def __init__(self) -> None:
        self.items: dict[str, str] = {}

    def put(self, name: str, digest: str) -> None:
        if name in self.items:
            raise KeyError(f"item hashed twice: {name}")
        self.items[name] = digest

    def array(self, name: str, a: np.ndarray | None) -> None:
        if a is not None:
            self.put(name, hash_array(np.asarray(a)))

    def stats(self, name: str, stats: dict[str, Any] | None) -> None:
        if stats is not None:
            self.put(name, hash_stats(stats))

    def render(self, name: str, res) -> None:
        """A ``RenderResult``: image, variance, alpha, sample_counts and stats."""
        self.array(f"{name}/image", res.image)
        self.array(f"{name}/variance", res.variance)
        self.array(f"{name}/alpha", res.alpha)
        self.array(f"{name}/sample_counts", res.sample_counts)
        self.stats(f"{name}/stats", res.stats)

    def records(self, name: str, cache) -> None:
        for key, a in sorted(cache.records().items()):
            self.array(f"{name}/records/{key}", a)
        self.stats(f"{name}/cache_stats", cache.stats())


def scene_items(vc, name: str, out: Hashes, threads: int, tmp: Path) -> None:
    """Hashes every item of scene ``name`` into ``out``."""
    t0 = time.perf_counter()
    setup = vc.scenes.load(name)
    camera = setup.camera.with_resolution(WIDTH, HEIGHT)
    log(f"{name}: loaded in {time.perf_counter() - t0:.1f} s")

    def step(label: str, work: Callable[[], None]) -> None:
        t = time.perf_counter()
        before = len(out.items)
        work()
        log(f"  {name} {label}: {len(out.items) - before} items, "
            f"{time.perf_counter() - t:.2f} s")

    def render(item: str, method: str, spp: int = SPP, **kw) -> None:
        res = vc.render(setup, camera=camera, spp=spp, method=method, seed=0,
                        threads=threads, progress=False, **kw)
        out.render(f"{name}/render/{item}", res)

    # Cache builds: one per preset, saved to a file each (cv renders below load fresh
    # copies, since a render writes the records' misses back to its cache).
    saved: dict[str, Path] = {}

    def caches() -> None:
        for preset in ("auto", "medium", "low"):
            cache = vc.VisibilityCache(setup.scene, preset=preset)
            report = cache.build(camera, seed=0, threads=threads, progress=False)
            item = f"{name}/cache/{preset}"
            out.stats(f"{item}/build", report)
            out.stats(f"{item}/params", cache.params)
            out.records(item, cache)
            path = tmp / f"{name}-{preset}.vcache"
            cache.save(path)
            out.put(f"{item}/file", hashlib.sha256(path.read_bytes()).hexdigest())
            saved[preset] = path

    def loaded(preset: str):
        return vc.VisibilityCache.load(saved[preset], setup.scene)

    def basic() -> None:
        for method in ("env", "bsdf", "mis", "product"):
            for jitter in (True, False):
                render(f"{method}/jitter={jitter}", method, jitter=jitter)
            render(f"{method}/adaptive", method, spp=ADAPTIVE_SPP, adaptive=True)
        render(f"product/spp={ODD_SPP}", "product", spp=ODD_SPP)
        render("product/light_samples=4", "product", light_samples=4)
        render("product/weights=product", "product", jitter=False,
               technique_weights={"product": 1.0})
        gbuffer = setup.scene.gbuffer(camera, jitter=False, threads=threads)
        for key in sorted(gbuffer.keys()):
            out.array(f"{name}/gbuffer/{key}", gbuffer[key])
        render("product/gbuffer", "product", gbuffer=gbuffer)
        render("mis/bounces=1", "mis", bounces=1)

    def control_variate() -> None:
        for jitter in (True, False):
            cache = loaded("medium")
            render(f"cv/medium/jitter={jitter}", "cv", cache=cache, jitter=jitter)
            out.records(f"{name}/render/cv/medium/jitter={jitter}/after", cache)
        render("cv/medium/alpha=estimate", "cv", cache=loaded("medium"), alpha="estimate")
        render("cv/medium/insert_missing", "cv", cache=loaded("medium"), insert_missing=True)
        render("cv/medium/adaptive", "cv", spp=ADAPTIVE_SPP, cache=loaded("medium"),
               adaptive=True)
        render("cv/auto/jitter=True", "cv", cache=loaded("auto"))
        for jitter in (True, False):
            render(f"cv/none/jitter={jitter}", "cv", cache=None, jitter=jitter)
        render("cv/none/alpha=estimate", "cv", cache=None, alpha="estimate")
        for jitter in (True, False):
            render(f"cv/none/spp={CV_SPP}/jitter={jitter}", "cv", spp=CV_SPP, cache=None,
                   jitter=jitter)

    def path() -> None:
        for jitter in (True, False):
            render(f"path/bounces=1/jitter={jitter}", "path", bounces=1, jitter=jitter)
        render("path/bounces=1/direct=False", "path", bounces=1, direct=False)
        render("path/bounces=1/adaptive", "path", spp=ADAPTIVE_SPP, bounces=1, adaptive=True)

    def vpl() -> None:
        vpls = vc.VPLs.trace(setup, VPL_COUNT, seed=0, camera=camera, threads=threads)
        for key in ("positions", "normals", "flux", "incident", "bounces", "kinds"):
            out.array(f"{name}/vpls/{key}", getattr(vpls, key))
        out.stats(f"{name}/vpls/stats", vpls.stats)
        for method in ("vpl", "vpl_sampled"):
            for jitter in (True, False):
                render(f"{method}/jitter={jitter}", method, spp=VPL_SPP, vpls=vpls,
                       jitter=jitter)
        render("vpl/clamp=0.3", "vpl", spp=VPL_SPP, vpls=vpls, clamp=0.3)

    def ambient() -> None:
        ao = vc.render_ao(setup, camera=camera, seed=0, threads=threads, progress=False)
        out.array(f"{name}/ao/cache/image", ao.image)
        out.stats(f"{name}/ao/cache/stats", ao.stats)
        out.records(f"{name}/ao/cache", ao.cache)
        ref = vc.render_ao(setup, camera=camera, reference_rays=16, seed=0, threads=threads,
                           progress=False)
        out.array(f"{name}/ao/reference/image", ref.image)
        out.stats(f"{name}/ao/reference/stats", ref.stats)

    def preview() -> None:
        cache = loaded("medium")
        out.array(f"{name}/preview/direct",
                  vc.preview(setup, cache, camera=camera, threads=threads))
        view = vc.LightingPreview(setup.scene, camera, threads=threads)
        # The default choice, then truncated bases: Haar within a small budget (which
        # traces rays toward the map's bright cells) and spherical harmonics.
        for basis, budget_mb in (("auto", None), ("haar", WIDTH * HEIGHT * 300 / 1e6),
                                 ("sh", None)):
            item = f"{name}/preview/{basis}"
            out.stats(f"{item}/prepare", view.prepare(cache, setup.envmap, basis=basis,
                                                      budget_mb=budget_mb, threads=threads))
            out.array(f"{item}/render", view.render(cache, setup.envmap, threads=threads))
            out.stats(f"{item}/last_bright", view.last_bright)
            out.array(f"{item}/render/rotation=90",
                      view.render(cache, setup.envmap, rotation=90.0, threads=threads))
            out.stats(f"{item}/last_bright/rotation=90", view.last_bright)

    def relight() -> None:
        def result(item: str, r) -> None:
            for key in ("image", "variance", "error_bound", "t", "bound", "visibility",
                        "effective_samples", "lbv_counts"):
                out.array(f"{item}/{key}", getattr(r, key))
            out.stats(f"{item}/stats", r.stats)

        rl = vc.Relighter(setup, camera, threads=threads)
        out.stats(f"{name}/relight/pixels/converge",
                  rl.converge_visibility(spp=32, seed=0, progress=False))
        result(f"{name}/relight/pixels", rl.render(lb_spp=16, lbv_spp=4, seed=0))
        result(f"{name}/relight/pixels/rotated",
               rl.render(envmap=setup.envmap.rotated(90.0), lb_spp=16, lbv_spp=4, seed=0))
        result(f"{name}/relight/pixels/threshold=0",
               rl.render(threshold=0.0, lbv_spp=4, seed=0))
        result(f"{name}/relight/pixels/classical",
               rl.render(threshold=0.0, lbv_spp=4, reuse=False, seed=0))
        objects = rl.gbuffer["object"]
        seen = int(np.bincount(objects[objects >= 0]).argmax())
        glossy = {seen: vc.Material.phong((0.3, 0.3, 0.3), (0.5, 0.5, 0.5), 20.0)}
        result(f"{name}/relight/pixels/material",
               rl.render(materials=glossy, lb_spp=16, lbv_spp=4, seed=0))
        cached = vc.Relighter(setup, camera, visibility="cache", threads=threads)
        out.records(f"{name}/relight/cache", cached.cache)
        result(f"{name}/relight/cache", cached.render(lb_spp=16, lbv_spp=4, seed=0))

    def variants() -> None:
        # The setups for indirect light and the animated scenes (their BVH refit).
        for variant in vc.scenes.variants(name):
            other = vc.scenes.load(name, variant=variant)
            for method, kw in (("product", {}), ("path", {"bounces": 1})):
                res = vc.render(other, camera=other.camera.with_resolution(WIDTH, HEIGHT),
                                spp=SPP, method=method, seed=0, threads=threads,
                                progress=False, **kw)
                out.render(f"{name}/variant/{variant}/{method}", res)
        if name in vc.scenes.animated_names():
            moving = vc.scenes.load(name, animated=True)
            moving.at_frame(10)
            res = vc.render(moving, camera=moving.camera.with_resolution(WIDTH, HEIGHT),
                            spp=SPP, method="product", seed=0, threads=threads,
                            progress=False)
            out.render(f"{name}/animated/frame=10/product", res)

    step("caches", caches)
    step("env/bsdf/mis/product", basic)
    step("cv", control_variate)
    step("path", path)
    step("vpl", vpl)
    step("ao", ambient)
    step("preview", preview)
    step("relight", relight)
    step("variants", variants)
    log(f"{name}: {time.perf_counter() - t0:.1f} s")


def record(out_path: Path, scenes: list[str] | None, threads: int) -> None:
    import viscache_rs as vc

    names = vc.scenes.names() if not scenes else scenes
    t0 = time.perf_counter()
    out = Hashes()
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            scene_items(vc, name, out, threads, Path(tmp))
    out_path.write_text(json.dumps(out.items, indent=1, sort_keys=True) + "\n")
    log(f"{len(out.items)} items over {len(names)} scenes in "
        f"{time.perf_counter() - t0:.1f} s (threads={threads}, viscache_rs "
        f"{vc.__version__} from {Path(vc.__file__).parent}) -> {out_path}")


def compare(before_path: Path, after_path: Path) -> int:
    """Prints every item that differs or is missing on one side; 1 if any, else 0."""
    before = json.loads(before_path.read_text())
    after = json.loads(after_path.read_text())
    common = sorted(before.keys() & after.keys())
    changed = [k for k in common if before[k] != after[k]]
    only_before = sorted(before.keys() - after.keys())
    only_after = sorted(after.keys() - before.keys())
    for k in changed:
        print(f"DIFFERS  {k}")
    for k in only_before:
        print(f"MISSING in {after_path}: {k}")
    for k in only_after:
        print(f"MISSING in {before_path}: {k}")
    print(f"{len(common)} items compared: {len(changed)} differ, {len(only_before)} only in "
          f"{before_path}, {len(only_after)} only in {after_path}")
    if changed or only_before or only_after:
        return 1
    print("all equal")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--out", type=Path, help="write {item: sha256} to this JSON file")
    mode.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"),
                      help="compare two such files; exit 1 if any item differs")
    parser.add_argument("--scenes", nargs="+", help="default: every vc.scenes.names()")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)
    if args.compare:
        return compare(*args.compare)
    record(args.out, args.scenes, args.threads)
    return 0


if __name__ == "__main__":
    sys.exit(main())
