"""BVH builders on the benchmark suite: what ``quality="auto"`` chooses and whether it chose
well. Per scene (its own objects), the binned SAH tree, obvhs's ``"slow"`` PLOC tree and the
tree ``"auto"`` keeps (which may be the SAH tree with each object in a subtree of its own):
build seconds, the probe work per ray that ``"auto"`` compares, and shadow-ray speed on the
peer-benchmark workloads (incoherent ground rays, record bundles), best of 7 calls on 2
threads.

    python benches/builders.py                 # every suite scene
    python benches/builders.py --scenes garage meshes
"""

from __future__ import annotations

import argparse
import time

import viscache_rs as vc

QUALITIES = ("sah", "slow", "auto")


def best_seconds(fn, calls: int = 7) -> float:
    fn()
    times = []
    for _ in range(calls):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def kept(stats: dict) -> str:
    return stats["quality"] + (" (objects apart)" if stats["objects_apart"] else "")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=None)
    args = ap.parse_args()
    print("| scene | auto keeps | work sah, slow, sah objects apart | incoherent Mr/s sah, slow,"
          " auto | bundles Mr/s sah, slow, auto | build s sah, slow, auto |")
    print("|---|---|---|---|---|---|")
    for name in args.scenes or vc.scenes.suite_names():
        scene = vc.scenes.load(name).scene
        workloads = {
            "incoherent": vc.testing.ground_hemisphere_rays(scene, 1 << 20, seed=1),
            "bundles": vc.testing.record_bundle_rays(scene, 1000, 32, seed=1),
        }
        speed = {w: [] for w in workloads}
        build = []
        for q in QUALITIES:
            build.append(scene.build(quality=q, threads=2))
            for w, (o, d) in workloads.items():
                seconds = best_seconds(lambda s=scene, o=o, d=d: s.occluded(o, d, threads=2))
                speed[w].append(len(o) / seconds / 1e6)
        stats = scene.bvh_stats()
        work = stats["auto_costs"]
        work_cell = (", ".join(f"{work[k]:.2f}" if k in work else "-"
                               for k in ("sah", "slow", "sah_objects_apart"))
                     if work else "(too large)")
        row = [name, kept(stats), work_cell,
               ", ".join(f"{v:.2f}" for v in speed["incoherent"]),
               ", ".join(f"{v:.2f}" for v in speed["bundles"]),
               ", ".join(f"{b:.2f}" for b in build)]
        print("| " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
