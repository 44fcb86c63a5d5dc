"""BVH builders on the benchmark suite: what ``quality="auto"`` chooses and whether it chose
well. Per scene, the binned SAH tree and obvhs's ``"slow"`` PLOC tree: build seconds, SAH
cost, the probe work per ray that ``"auto"`` compares, and shadow-ray speed on the
peer-benchmark workloads (incoherent ground rays, record bundles), best of 7 calls on 2
threads.

    python benches/builders.py                 # every suite scene
    python benches/builders.py --scenes garage meshes
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import viscache_rs as vc


def best_seconds(fn, calls: int = 7) -> float:
    fn()
    times = []
    for _ in range(calls):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def scene_of(triangles: np.ndarray, quality: str) -> tuple[vc.Scene, float]:
    s = vc.Scene()
    s.add_mesh(triangles.reshape(-1, 3), np.arange(3 * len(triangles)).reshape(-1, 3))
    return s, s.build(quality=quality, threads=2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=None)
    args = ap.parse_args()
    print("| scene | auto keeps | work sah/slow | SAH cost sah, slow | incoherent Mr/s sah, slow"
          " | bundles Mr/s sah, slow | build s sah, slow, auto |")
    print("|---|---|---:|---|---|---|---|")
    for name in args.scenes or vc.scenes.suite_names():
        setup = vc.scenes.load(name)
        tris = setup.scene.triangles()
        workloads = {
            "incoherent": vc.testing.ground_hemisphere_rays(setup.scene, 1 << 20, seed=1),
            "bundles": vc.testing.record_bundle_rays(setup.scene, 1000, 32, seed=1),
        }
        built = {q: scene_of(tris, q) for q in ("sah", "slow", "auto")}
        auto = built["auto"][0].bvh_stats()
        work = auto["auto_costs"]
        ratio = f"{work['sah'] / work['slow']:.2f}" if work else "(too large)"
        speed = {
            w: [len(o) / best_seconds(lambda s=built[q][0], o=o, d=d: s.occluded(o, d, threads=2))
                / 1e6 for q in ("sah", "slow")]
            for w, (o, d) in workloads.items()
        }
        cost = [built[q][0].bvh_stats()["sah_cost"] for q in ("sah", "slow")]
        print(f"| {name} | {auto['quality']} | {ratio} | {cost[0]:.2f}, {cost[1]:.2f} "
              f"| {speed['incoherent'][0]:.2f}, {speed['incoherent'][1]:.2f} "
              f"| {speed['bundles'][0]:.2f}, {speed['bundles'][1]:.2f} "
              f"| {built['sah'][1]:.2f}, {built['slow'][1]:.2f}, {built['auto'][1]:.2f} |",
              flush=True)


if __name__ == "__main__":
    main()
