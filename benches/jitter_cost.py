"""What antialiasing costs: the time of a jittered render (a primary ray per sample) over the
same render with every sample at its pixel's centre hit (issue 22 §1, target 1.3).

Per suite scene: ``vc.render(setup, spp=64, method="product", jitter=True)`` and the same
with ``jitter=False``, 160x120, 2 threads, one warm-up call each, then ``--repeats`` calls
of each in turn; the best of each is kept. Prints the seconds, the ratio per scene, how many
scenes are within 1.3, the geometric mean and the worst scene.

Beside each ratio, its floor: the ratio the jittered render would have if a sample cost
what a fixed one does plus its own primary ray, ``1 + p / c`` with ``p`` the CPU seconds of
the jittered samples' primary rays (``stats["sample_primary_seconds"]``: their packets from
the eye and the hits' surfaces) and ``c`` the fixed render's CPU seconds (its anchors'
primary rays and its samples). No saving in the rest of a sample goes below it; only
faster primary rays do (``benches/peer_embree.py`` compares those rays with Embree's).

    python benches/jitter_cost.py                     # every suite scene
    python benches/jitter_cost.py garden strands --repeats 5
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import viscache_rs as vc

TARGET = 1.3


def timed(fn):
    """The seconds ``fn()`` took, and what it returned."""
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--size", default="160x120")
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    print(f"our kernels: {vc.testing.simd_level()}; {args.size}, {args.spp} spp, product, "
          f"best of {args.repeats}")
    print("| scene | jitter / fixed (s) | ratio | floor |\n|---|---|---:|---:|")
    ratios, floors = {}, {}
    for name in args.scenes or vc.scenes.suite_names():
        setup = vc.scenes.load(name)
        camera = setup.camera.with_resolution(width, height)

        def render(jitter: bool, setup=setup, camera=camera) -> dict:
            return vc.render(setup, camera, spp=args.spp, method="product", jitter=jitter,
                             threads=2, progress=False).stats

        render(True)
        render(False)
        jittered, fixed = [], []
        for _ in range(args.repeats):
            jittered.append(timed(lambda: render(True)))
            fixed.append(timed(lambda: render(False)))
        # The fastest run of each, with its stats.
        (t_jittered, jittered_stats), (t_fixed, fixed_stats) = (
            min(runs, key=lambda r: r[0]) for runs in (jittered, fixed))
        ratios[name] = t_jittered / t_fixed
        fixed_cpu = fixed_stats["primary_seconds"] + fixed_stats["direct_seconds"]
        floors[name] = 1.0 + jittered_stats["sample_primary_seconds"] / fixed_cpu
        mark = "**" if ratios[name] > TARGET else ""
        print(f"| {name} | {t_jittered:.3f} / {t_fixed:.3f} | "
              f"{mark}{ratios[name]:.2f}{mark} | {floors[name]:.2f} |", flush=True)
    worst = max(ratios, key=ratios.get)
    within = sum(r <= TARGET for r in ratios.values())
    mean = float(np.exp(np.mean(np.log(list(ratios.values())))))
    print(f"\n{within} of {len(ratios)} within {TARGET} (geometric mean {mean:.2f}, "
          f"worst {worst} {ratios[worst]:.2f}); floors above {TARGET}: "
          + (", ".join(f"{n} {f:.2f}" for n, f in floors.items() if f > TARGET) or "none"))


if __name__ == "__main__":
    main()
