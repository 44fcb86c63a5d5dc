"""The ``viscache`` command line.

``viscache demo``   render a built-in scene's direct illumination by MIS and by product
                    importance sampling, write PNGs and print time, speed and noise;
                    then build the visibility cache for the view and print its size and
                    cost.
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


def demo(args: argparse.Namespace) -> int:
    from .render import render

    t = time.perf_counter()
    setup = scenes.load(args.scene, detail=args.detail, seed=args.seed)
    generate_s = time.perf_counter() - t
    setup.camera = setup.camera.with_resolution(args.width, args.height)
    scene = setup.scene
    print(f"scene {args.scene}: {scene.num_triangles:,} triangles, {scene.num_objects} objects, "
          f"{len(scene.area_lights())} area lights, env map {setup.envmap.resolution}^2")
    t = time.perf_counter()
    scene.build(threads=args.threads)
    build_s = time.perf_counter() - t
    print(f"{'generate scene':<22}{generate_s:>10.3f} s")
    print(f"{'BVH build':<22}{build_s:>10.3f} s")
    lum = np.array([0.2126, 0.7152, 0.0722])
    for method in args.methods.split(","):
        res = render(setup, spp=args.spp, method=method, seed=args.seed, threads=args.threads,
                     time_budget=args.time_budget, progress=not args.quiet)
        s = res.stats
        out = write_png(Path(args.out) / f"{args.scene}_{method}.png", to_srgb8(res.image))
        noise = float(np.sqrt(np.mean(res.variance @ lum**2)))
        print(f"{method:<8} {s['spp']:>5} spp {s['seconds']:>8.3f} s  "
              f"{s['samples_per_second'] / 1e6:6.3f} Msamples/s  {s['rays_per_second'] / 1e6:6.2f} "
              f"Mrays/s  rms standard error {noise:.4g}  -> {out}")
    from ._core import VisibilityCache

    cache = VisibilityCache(scene)
    b = cache.build(setup.camera, seed=args.seed, threads=args.threads, progress=not args.quiet)
    print(f"{'visibility cache':<22}{b['seconds']:>10.3f} s  {b['records']:,} records "
          f"({cache.memory_bytes() / 1e6:.2f} MB), {b['shadow_rays_per_pixel']:.2f} shadow "
          f"rays/pixel amortised")
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
    p = sub.add_parser("demo", help="render a built-in scene by each method, with timings")
    p.add_argument("--scene", default="garage", choices=scenes.names())
    p.add_argument("--detail", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--width", type=int, default=512)
    p.add_argument("--height", type=int, default=384)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--time-budget", type=float, default=None,
                   help="seconds per method instead of a fixed spp")
    p.add_argument("--methods", default="mis,product",
                   help="comma-separated: env, bsdf, mis, product")
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
