"""The ``viscache`` command line.

``viscache demo``   build the visibility cache for garage's view, render it by product
                    sampling with the cache's control variate (CAM08) and by plain product
                    sampling at equal time, print the table and write the images side
                    by side.
``viscache scenes`` list the built-in scenes.
``viscache experiment NAME [--quick]``
                    run an experiment (``viscache experiment --list``) and write
                    ``results/NAME/``: JSON of every figure, markdown tables, images, plots.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from . import scenes
from .io import to_srgb8, write_png

LUM = np.array([0.2126, 0.7152, 0.0722])


def _mean_variance(res) -> float:
    return float((res.variance @ LUM**2).mean())


def demo(args: argparse.Namespace) -> int:
    """Equal-time product sampling against the cache's control variate (CAM08 Fig. 13)."""
    from ._core import VisibilityCache
    from .render import render

    t = time.perf_counter()
    setup = scenes.load(args.scene, detail=args.detail, seed=args.seed)
    setup.camera = setup.camera.with_resolution(args.width, args.height)
    scene = setup.scene
    scene.build(threads=args.threads)
    print(f"scene {args.scene}: {scene.num_triangles:,} triangles, {args.width}x{args.height}, "
          f"env map {setup.envmap.resolution}^2 (generated and BVH built in "
          f"{time.perf_counter() - t:.2f} s)")
    quiet = args.quiet
    cache = VisibilityCache(scene, resolution=args.resolution, preset=args.preset,
                            nearest_hits=False)
    b = cache.build(setup.camera, seed=args.seed, threads=args.threads, progress=not quiet)
    print(f"visibility cache: {b['records']:,} records of {args.resolution}x{args.resolution} "
          f"({cache.memory_bytes() / 1e6:.2f} MB), {b['shadow_rays_per_pixel']:.1f} shadow rays "
          f"per pixel, built in {b['seconds']:.2f} s")
    alpha = args.alpha if args.alpha == "estimate" else float(args.alpha)
    cv = render(setup, spp=args.spp, method="cv", cache=cache, alpha=alpha, seed=args.seed,
                threads=args.threads, progress=not quiet)
    cv_total = cv.stats["seconds"] + b["seconds"]
    # Product sampling's time is about a + b * spp (per-pixel setup plus samples): fit it
    # on two runs, then give it the spp that takes as long as the cache build plus cv.
    same = render(setup, spp=args.spp, method="product", seed=args.seed + 3,
                  threads=args.threads, progress=False)
    probe = render(setup, spp=max(1, args.spp // 4), method="product", seed=args.seed + 1,
                   threads=args.threads, progress=False)
    b_spp = (same.stats["seconds"] - probe.stats["seconds"]) / max(
        same.stats["spp"] - probe.stats["spp"], 1)
    # Tiny images time too fast to fit: never less than a tenth of the mean cost per sample.
    b_spp = max(b_spp, 0.1 * same.stats["seconds"] / same.stats["spp"])
    a_fixed = same.stats["seconds"] - b_spp * same.stats["spp"]
    spp_equal = int(np.clip(round((cv_total - a_fixed) / b_spp), 2, 64 * args.spp))
    prod = render(setup, spp=spp_equal, method="product", seed=args.seed + 2,
                  threads=args.threads, progress=not quiet)
    rows = [
        ("product", same.stats["spp"], same.stats["seconds"], _mean_variance(same)),
        ("product (equal time)", prod.stats["spp"], prod.stats["seconds"], _mean_variance(prod)),
        ("cv (render only)", cv.stats["spp"], cv.stats["seconds"], _mean_variance(cv)),
        ("cv (with cache build)", cv.stats["spp"], cv_total, _mean_variance(cv)),
    ]
    print(f"\n{'method':<24}{'spp':>6}{'seconds':>10}{'variance':>12}{'ratio':>8}")
    for name, spp, sec, var in rows:
        base = _mean_variance(same) if "equal" not in name and "build" not in name \
            else _mean_variance(prod)
        print(f"{name:<24}{spp:>6}{sec:>10.3f}{var:>12.4g}{var / base:>8.3f}")
    print(f"\nequal samples ({args.spp} spp): variance ratio cv/product "
          f"{_mean_variance(cv) / _mean_variance(same):.3f}, time overhead "
          f"{100 * (cv.stats['seconds'] / same.stats['seconds'] - 1):.0f}% (render only)")
    print(f"equal time ({cv_total:.2f} s with the cache build): variance ratio cv/product "
          f"{_mean_variance(cv) / _mean_variance(prod):.3f}")
    out = Path(args.out)
    exposure = 0.18 / max(float(np.median(prod.image @ LUM)), 1e-6)
    gap = np.ones_like(prod.image[:, :8])
    side = write_png(out / f"{args.scene}_product_vs_cv.png",
                     to_srgb8(np.concatenate([prod.image, gap, cv.image], axis=1), exposure))
    write_png(out / f"{args.scene}_product.png", to_srgb8(prod.image, exposure))
    write_png(out / f"{args.scene}_cv.png", to_srgb8(cv.image, exposure))
    print(f"wrote {side} (left: product at {prod.stats['spp']} spp, right: cv at "
          f"{cv.stats['spp']} spp, equal time)")
    return 0


def list_scenes(_args: argparse.Namespace) -> int:
    print(scenes.__doc__)
    return 0


def experiment(args: argparse.Namespace) -> int:
    from . import experiments

    if args.list or args.name is None:
        for name in experiments.names():
            print(f"{name:<16}{experiments.describe(name).strip().splitlines()[0]}")
        return 0 if args.list else 2
    ctx = experiments.run(args.name, quick=args.quick, out=args.out, seed=args.seed,
                          threads=args.threads, progress=not args.quiet)
    print(f"wrote {ctx.out}/ in {ctx.results['seconds']:.1f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="viscache", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("demo", help="equal-time product sampling vs the cache's control variate")
    p.add_argument("--scene", default="garage", choices=scenes.names())
    p.add_argument("--detail", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--width", type=int, default=512)
    p.add_argument("--height", type=int, default=384)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--spp", type=int, default=16, help="samples per pixel of the cv render")
    p.add_argument("--resolution", type=int, default=64, help="record resolution (2..128)")
    p.add_argument("--preset", default="medium", choices=["low", "medium", "high"])
    p.add_argument("--alpha", default="estimate",
                   help="control-variate alpha: a number in [0, 2] or 'estimate'")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--out", default="results/demo")
    p.set_defaults(func=demo)
    p = sub.add_parser("experiment", help="run an experiment and write results/NAME/")
    p.add_argument("name", nargs="?", help="the experiment (--list shows them)")
    p.add_argument("--list", action="store_true", help="list the experiments")
    p.add_argument("--quick", action="store_true", help="minutes on 2 cores")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--out", default="results", help="parent directory of results/NAME/")
    p.set_defaults(func=experiment)
    p = sub.add_parser("scenes", help="list the built-in scenes")
    p.set_defaults(func=list_scenes)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
