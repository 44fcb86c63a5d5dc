"""Times the same shadow rays through viscache_rs and Embree (embreex) and checks that the
answers agree.

Workloads (identical rays for both, from ``viscache_rs.testing``):
  incoherent  2^20 rays from points on the ground, directions uniform on the hemisphere;
  bundles     1000 ground points x 1024 stratified hemisphere directions, point after point
              (how visibility records are built);
  shading     the view's jittered first hits at 160x120, 32 passes in pixel order, one
              cosine-weighted direction each (what a render shades with);
  camera      closest hits, not occlusion: the view's jittered camera rays at 160x120,
              16 passes (``Camera.rays``), through ``Scene.intersect`` (which also returns
              hit points and normals) and embreex's ``DISTANCE`` query; answers agree
              where both miss or the distances agree to 1e-3 relative.
  pixels      the same rays pixel after pixel, each pixel's 16 together: the order in
              which a jittered render traces its samples' primary rays (as packets).

viscache_rs runs with threads=2; embreex runs two Python threads on the two halves of the
rays (``EmbreeScene.run(..., query='OCCLUDED')``), once with robust=False and once with its
default robust=True. Prints rays/s and our/embree ratios (> 1: we are faster).

The three are timed in turn within each repeat (ours, Embree fast, Embree robust), so a
drift of the machine's speed hits all three alike; each repeat gives a ratio, and the
median ratio over the repeats is reported with its least and greatest.

Without ``--scenes`` every scene of the benchmark suite runs (``vc.scenes.suite_names()``,
the real meshes included when found), and the worst scene is printed beside the geometric
mean of each workload's ratios, with the builder the default build chose per scene.

    python benches/peer_embree.py [--scenes garden cornell] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import viscache_rs as vc


def timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def interleaved_times(fns: dict, repeats: int, min_seconds: float = 0.05) -> dict:
    """Seconds per call of each of ``fns``, ``repeats`` times, the functions run in turn
    within a repeat. A timing spans enough calls (the same count for every function) that
    the slowest function's takes ``min_seconds``: a single call of 10 ms is at the mercy
    of a neighbour's burst on this machine, and its ratios then spread by 2x."""
    warm = [timed(fn) for fn in fns.values()]
    calls = max(1, int(np.ceil(min_seconds / max(max(warm), 1e-9))))
    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            for _ in range(calls):
                fn()
            times[name].append((time.perf_counter() - t) / calls)
    return times


def embree_run(es, origins, dirs, pool, query: str) -> np.ndarray:
    half = len(origins) // 2
    parts = [(origins[:half], dirs[:half]), (origins[half:], dirs[half:])]
    futures = [pool.submit(es.run, o, d, None, query) for o, d in parts]
    return np.concatenate([f.result() for f in futures])


def embree_occluded(es, origins, dirs, pool) -> np.ndarray:
    return embree_run(es, origins, dirs, pool, "OCCLUDED") >= 0


def embree_distance(es, origins, dirs, pool) -> np.ndarray:
    """Hit distances, inf where the ray misses."""
    t = embree_run(es, origins, dirs, pool, "DISTANCE").astype(np.float64)
    return np.where(t < 1e30, t, np.inf)


def camera_rays(setup, passes: int = 16, by_pixel: bool = False
                ) -> tuple[np.ndarray, np.ndarray]:
    """``passes`` jittered rays per pixel at 160x120, pass after pass or (``by_pixel``)
    pixel after pixel."""
    cam = setup.camera.with_resolution(160, 120)
    rays = [cam.rays(seed=k, jitter=True) for k in range(passes)]
    origins, dirs = (np.stack([r[i] for r in rays]) for i in (0, 1))  # (pass, pixel, 3)
    if by_pixel:
        origins, dirs = origins.swapaxes(0, 1), dirs.swapaxes(0, 1)
    return (np.ascontiguousarray(origins.reshape(-1, 3), np.float32),
            np.ascontiguousarray(dirs.reshape(-1, 3), np.float32))


def same_hits(ours: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    both_miss = ~np.isfinite(ours) & ~np.isfinite(theirs)
    with np.errstate(invalid="ignore"):
        close = np.abs(ours - theirs) <= 1e-3 * np.abs(theirs)
    return both_miss | close


def run(scene_name: str, repeats: int) -> dict:
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh

    setup = vc.scenes.load(scene_name)
    scene = setup.scene
    build_s = scene.build(threads=2)
    stats = scene.bvh_stats()
    builder = stats["quality"] + (" (objects apart)" if stats["objects_apart"] else "")
    tris = scene.triangles()
    workloads = {
        "incoherent": vc.testing.ground_hemisphere_rays(scene, 1 << 20, seed=1),
        "bundles": vc.testing.record_bundle_rays(scene, 1000, 32, seed=1),
        "shading": vc.testing.view_shading_rays(setup, seed=1),
        "camera": camera_rays(setup),
        "pixels": camera_rays(setup, by_pixel=True),
    }
    result = {"scene": scene_name, "triangles": int(scene.num_triangles),
              "our_build_s": build_s, "builder": builder, "workloads": {}}
    pool = ThreadPoolExecutor(2)
    embree = {}
    for robust in (False, True):
        t = time.perf_counter()
        es = rtcs.EmbreeScene(robust=robust)
        TriangleMesh(es, tris)
        es.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32), query="OCCLUDED")
        embree[robust] = (es, time.perf_counter() - t)
    for name, (o, d) in workloads.items():
        if name in ("camera", "pixels"):
            def query(o=o, d=d):
                return scene.intersect(o, d, threads=2)["t"].astype(np.float64)
            peer, agree, hit = embree_distance, same_hits, np.isfinite
        else:
            def query(o=o, d=d):
                return scene.occluded(o, d, threads=2)
            peer, agree, hit = embree_occluded, np.equal, np.asarray
        ours = query()
        fns = {"ours": query}
        for robust, (es, _) in embree.items():
            key = "robust" if robust else "fast"
            fns[key] = lambda es=es, o=o, d=d, peer=peer: peer(es, o, d, pool)
        times = interleaved_times(fns, repeats)
        t_ours = min(times["ours"])
        row = {"rays": len(o), "occluded_fraction": float(hit(ours).mean()),
               "ours_rays_per_s": len(o) / t_ours, "ours_s": t_ours}
        for robust, (es, build) in embree.items():
            theirs = peer(es, o, d, pool)
            key = "robust" if robust else "fast"
            ratios = np.array(times[key]) / np.array(times["ours"])
            row[f"embree_{key}_s"] = min(times[key])
            row[f"embree_{key}_build_s"] = build
            row[f"ratio_vs_embree_{key}"] = float(np.median(ratios))
            row[f"ratio_vs_embree_{key}_range"] = [float(ratios.min()), float(ratios.max())]
            row[f"agreement_{key}"] = float(agree(ours, theirs).mean())
        result["workloads"][name] = row
    pool.shutdown()
    return result


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--scenes", nargs="+", default=None)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", default="results/peer_embree.json")
    args = ap.parse_args()
    names = args.scenes or vc.scenes.suite_names()
    results = []
    for k, name in enumerate(names):
        t = time.perf_counter()
        results.append(run(name, args.repeats))
        print(f"[{k + 1}/{len(names)}] {name}: {time.perf_counter() - t:.0f} s",
              file=sys.stderr, flush=True)
    print(f"ratios: median over the repeats [least, greatest]; our kernels: "
          f"{vc.testing.simd_level()}")
    print(f"{'scene':<9}{'workload':<12}{'rays':>9}{'occl.':>7}{'ours Mr/s':>11}"
          f"{'x fast':>20}{'x robust':>20}{'agree fast':>12}{'agree rob.':>12}")

    def ratio(w, key):
        lo, hi = w[f"ratio_vs_embree_{key}_range"]
        return f"{w[f'ratio_vs_embree_{key}']:.2f} [{lo:.2f}, {hi:.2f}]"

    for r in results:
        for name, w in r["workloads"].items():
            print(f"{r['scene']:<9}{name:<12}{w['rays']:>9}{w['occluded_fraction']:>7.3f}"
                  f"{w['ours_rays_per_s'] / 1e6:>11.2f}{ratio(w, 'fast'):>20}"
                  f"{ratio(w, 'robust'):>20}{w['agreement_fast']:>12.5f}"
                  f"{w['agreement_robust']:>12.5f}")
    print(f"\n{'workload':<12}{'geomean x fast':>16}{'worst x fast':>26}{'least agreement':>17}")
    for name in results[0]["workloads"]:
        ratios = {r["scene"]: r["workloads"][name]["ratio_vs_embree_fast"] for r in results}
        s = vc.metrics.worst_and_mean(ratios, higher_is_worse=False)
        agree = min(r["workloads"][name]["agreement_fast"] for r in results)
        print(f"{name:<12}{s['geomean']:>16.2f}{s['worst']:>18} ({s['worst_value']:.2f})"
              f"{agree:>17.5f}")
    print("builders: " + ", ".join(f"{r['scene']} {r['builder']} ({r['our_build_s']:.2f} s)"
                                    for r in results))
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(results, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
