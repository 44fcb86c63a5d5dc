"""The many-light renderer over virtual point lights (issue 25, sec. 2-3): for cornell and
garage at 256 x 192, the one-bounce indirect image (``direct=False``) by the full VPL sum of
1k, 10k and 100k VPLs of indirect light (importance-driven, no light VPLs, one jittered
sample per pixel), and per count the
VPL trace's seconds, the time per frame, shadow rays per second in the gather and the
relMSE against the path-traced reference ``vc.render(setup, method="path", bounces=1,
direct=False, spp=...)``, unclamped (unbiased for the set: its error is mostly the bright
spots of VPLs near surfaces) and, with ``--clamp C``, with the geometry term bounded by C
(biased). The target on cornell is >= 50 M shadow rays/s on two cores. Timings on a shared
machine are indicative only.

    python benches/vpl.py [--counts 1000 10000 100000] [--ref-spp 256] [--threads 2]
                          [--clamp 1.0]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import viscache_rs as vc


def relmse(x: np.ndarray, ref: np.ndarray) -> float:
    """Mean over pixels and channels of (x - ref)^2 / (ref^2 + 1e-2)."""
    return float(np.mean((x - ref) ** 2 / (ref**2 + 1e-2)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["cornell", "garage"])
    ap.add_argument("--counts", nargs="+", type=int, default=[1000, 10_000, 100_000])
    ap.add_argument("--ref-spp", type=int, default=256)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--width", type=int, default=256)
    ap.add_argument("--height", type=int, default=192)
    ap.add_argument("--no-importance", action="store_true")
    ap.add_argument("--clamp", type=float, default=None)
    args = ap.parse_args()

    print(f"{os.cpu_count()} cores seen, {args.threads} threads; shared machine: "
          "timings indicative only")
    for name in args.scenes:
        setup = vc.scenes.load(name)
        cam = setup.camera.with_resolution(args.width, args.height)
        t = time.perf_counter()
        ref = vc.render(setup, camera=cam, method="path", bounces=1, direct=False,
                        spp=args.ref_spp, seed=1, threads=args.threads, progress=False)
        ref_seconds = time.perf_counter() - t
        ref_noise = float(np.mean(ref.variance / (ref.image**2 + 1e-2)))
        print(f"\n{name} {args.width}x{args.height}: reference path bounces=1 direct=False "
              f"{args.ref_spp} spp in {ref_seconds:.1f} s (its own relMSE ~{ref_noise:.2e})")
        print(f"{'VPLs':>8} {'surface':>8} {'trace s':>8} {'frame s':>8} {'shadow rays':>12} "
              f"{'M rays/s':>9} {'relMSE':>9}" + (" clamped" if args.clamp else ""))
        for count in args.counts:
            vpls = vc.VPLs.trace(setup, count=count, seed=0, threads=args.threads,
                                 importance=not args.no_importance, lights=False)
            res = vc.render(setup, camera=cam, method="vpl", vpls=vpls, direct=False, spp=1,
                            seed=0, threads=args.threads, progress=False)
            s = res.stats
            clamped = ""
            if args.clamp:
                c = vc.render(setup, camera=cam, method="vpl", vpls=vpls, direct=False, spp=1,
                              seed=0, threads=args.threads, progress=False, clamp=args.clamp)
                clamped = f" {relmse(c.image, ref.image):>8.2e}"
            print(f"{len(vpls):>8} {int((vpls.bounces >= 1).sum()):>8} "
                  f"{vpls.stats['seconds']:>8.3f} {s['seconds']:>8.2f} {s['shadow_rays']:>12} "
                  f"{s['shadow_rays_per_second'] / 1e6:>9.1f} "
                  f"{relmse(res.image, ref.image):>9.2e}{clamped}")


if __name__ == "__main__":
    main()
