"""The viscache command line.

viscache demo       build the visibility cache for garage's view, render it by product
                    sampling with the cache's control variate (CAM08) and by plain product
                    sampling at equal time, print the table and write three PNGs to
                    results/demo/: SCENE_product_vs_cv.png (side by side),
                    SCENE_product.png and SCENE_cv.png.
viscache preview SCENE --rotate A:B:STEP --out DIR
                    lighting design (CAM08 §6.2): prepare the cached transfer of SCENE's
                    view, render one preview frame per rotation of the map about +y (A,
                    A+STEP, ... below B, in degrees) into DIR/SCENE_000.png, ... and print
                    the preparation's cost and the milliseconds per frame.
viscache scenes     list the built-in scenes.
viscache experiment NAME [--quick] [--scheduler ADDRESS]
                    run an experiment (viscache experiment --list) and write
                    results/NAME/: JSON of every figure, markdown tables, images, plots.
                    tradeoff and variance-table run their renders as a sweep: in this
                    process, or on the Dask cluster at ADDRESS ("local": a new one here).
viscache sweep CONFIG [--scheduler ADDRESS] [--workers N] [--out DIR]
                    run the points of a sweep file (JSON or TOML; README "Sweeps"), one
                    Dask task each, on a new LocalCluster (one worker per core) or the
                    cluster at ADDRESS (tcp://host:port); write DIR/sweep.parquet (one
                    row per point) and DIR/efficiency.png, and print the table.
viscache --version  the version.

Every option is checked before any work, against the library's own ranges.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import re
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__, design, metrics, scenes
from ._core import LIMITS
from .io import auto_exposure, to_srgb8, write_png


def _bars(quiet: bool) -> bool | None:
    """``progress=`` for a command: none with ``--quiet``, else a bar when stderr is a
    terminal (None), so that a command whose stderr goes to a log writes no bar lines."""
    return False if quiet else None


def _ratios(res, base) -> str:
    rgb, mean = metrics.variance_ratio(res.variance, base.variance)
    return f"{rgb[0]:.3f} / {rgb[1]:.3f} / {rgb[2]:.3f} (mean {mean:.3f})"


def demo(args: argparse.Namespace) -> int:
    """Equal-time product sampling against the cache's control variate (CAM08 Fig. 13)."""
    from .cache import VisibilityCache
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
    # One G-buffer: the records' points and the renders' anchors.
    gbuffer = scene.gbuffer(setup.camera, jitter=False, threads=args.threads)
    b = cache.build(gbuffer=gbuffer, seed=args.seed, threads=args.threads,
                    progress=_bars(quiet))
    print(f"visibility cache: {b['records']:,} records of {cache.resolution}x"
          f"{cache.resolution} ({cache.memory_bytes() / 1e6:.2f} MB), "
          f"{b['shadow_rays_per_pixel']:.1f} shadow rays per pixel, built in "
          f"{b['seconds']:.2f} s")
    cv = render(setup, spp=args.spp, method="cv", cache=cache, alpha=args.alpha, seed=args.seed,
                threads=args.threads, progress=_bars(quiet), gbuffer=gbuffer)
    cv_total = cv.stats["seconds"] + b["seconds"]
    same = render(setup, spp=args.spp, method="product", seed=args.seed + 3,
                  threads=args.threads, progress=False, gbuffer=gbuffer)
    # Product sampling given the time of the cache build and the cv render together.
    prod = render(setup, method="product", time_budget=cv_total, seed=args.seed + 2,
                  threads=args.threads, progress=_bars(quiet), gbuffer=gbuffer)
    print(f"\n{'method':<24}{'spp':>6}{'seconds':>10}")
    for name, res, sec in (("product", same, same.stats["seconds"]),
                           ("product (equal time)", prod, prod.stats["seconds"]),
                           ("cv (render only)", cv, cv.stats["seconds"]),
                           ("cv (with cache build)", cv, cv_total)):
        print(f"{name:<24}{res.stats['spp']:>6}{sec:>10.3f}")
    print(f"\nequal samples ({args.spp} spp): variance ratio cv/product R/G/B "
          f"{_ratios(cv, same)}, time overhead "
          f"{100 * (cv.stats['seconds'] / same.stats['seconds'] - 1):.0f}% (render only)")
    print(f"equal time ({cv_total:.2f} s with the cache build): variance ratio cv/product "
          f"R/G/B {_ratios(cv, prod)}")
    out = Path(args.out)
    exposure = auto_exposure(prod.image)
    gap = np.ones_like(prod.image[:, :8])
    side = write_png(out / f"{args.scene}_product_vs_cv.png",
                     to_srgb8(np.concatenate([prod.image, gap, cv.image], axis=1), exposure))
    write_png(out / f"{args.scene}_product.png", to_srgb8(prod.image, exposure))
    write_png(out / f"{args.scene}_cv.png", to_srgb8(cv.image, exposure))
    print(f"wrote {side} (left: product at {prod.stats['spp']} spp, right: cv at "
          f"{cv.stats['spp']} spp, equal time)")
    return 0


def preview(args: argparse.Namespace) -> int:
    """One preview frame per rotation from the cached transfer (CAM08 §6.2)."""
    from ._core import LightingPreview
    from .cache import VisibilityCache

    setup = scenes.load(args.scene)
    cam = setup.camera.with_resolution(args.width, args.height)
    try:
        env = design.envmap(setup, args.envmap)
    except ValueError as e:
        print(f"viscache preview: {e}", file=sys.stderr)
        return 2
    setup.scene.build(threads=args.threads)
    cache = VisibilityCache(setup.scene)
    b = cache.build(cam, threads=args.threads, progress=_bars(args.quiet))
    pv = LightingPreview(setup.scene, cam, threads=args.threads)
    info = pv.prepare(cache, env, basis=args.basis, budget_mb=args.budget_mb,
                      threads=args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ms: list[float] = []
    exposure = 1.0
    for i, deg in enumerate(args.rotate):
        t = time.perf_counter()
        img = pv.render(cache, env, rotation=deg, threads=args.threads)
        ms.append(1e3 * (time.perf_counter() - t))
        if i == 0:
            # One exposure for all frames, so that they show how the rotation changes the
            # light rather than each being evened out.
            exposure = auto_exposure(img)
        write_png(out / f"{args.scene}_{i:03d}.png", to_srgb8(img, exposure))
    basis = info["basis"]
    if "terms" in info:
        basis += f" ({info['terms']} terms)"
    elif "basis_level" in info:
        basis += f" (level {info['basis_level']})"
    print(f"{args.scene} {args.width}x{args.height}, {args.envmap} map, cache "
          f"{b['records']:,} records: wrote {len(ms)} frames "
          f"({args.rotate[0]:g} to {args.rotate[-1]:g} deg) to {out}/")
    print(f"prepare {info['seconds']:.2f} s, {info['bytes'] / 1e6:.1f} MB, basis {basis}; "
          f"render median {np.median(ms):.1f} ms, max {max(ms):.1f} ms per frame "
          f"(render only, {len(ms)} frames)")
    return 0


def _rotations(spec: str) -> list[float]:
    try:
        return design.rotations(spec)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e).removeprefix("rotate: ")) from None


def _positive(kind: type) -> Callable[[str], Any]:
    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"must be positive and finite, got {text!r}")
        return value

    return parse


def _integer(limit: str) -> Callable[[str], int]:
    """An argparse type: an integer within the core's own range ``LIMITS[limit]``, so the
    command refuses before any work what the library would refuse after it."""
    low, high = LIMITS[limit]

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not low <= value <= high:
            raise argparse.ArgumentTypeError(
                f"must be an integer in {low}..{high}, got {text!r}")
        return value

    return parse


def _number(limit: str, open_low: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number within ``LIMITS[limit]`` (above its low end when
    ``open_low``)."""
    low, high = LIMITS[limit]

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        inside = (low < value if open_low else low <= value) and value <= high
        if not inside:  # NaN is never inside
            interval = f"{'(' if open_low else '['}{low:g}, {high:g}]"
            raise argparse.ArgumentTypeError(f"must be a number in {interval}, got {text!r}")
        return value

    return parse


def _record_resolution(text: str) -> int:
    low, high = LIMITS["record_resolution"]
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not (low <= value <= high and value & (value - 1) == 0):
        raise argparse.ArgumentTypeError(
            f"must be a power of two in {low}..{high}, got {text!r}")
    return value


def _alpha(text: str) -> str | float:
    if text == "estimate":
        return text
    low, high = LIMITS["alpha"]
    try:
        return _number("alpha")(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"must be a number in [{low:g}, {high:g}] or 'estimate', got {text!r}") from None


def _folder(text: str) -> str:
    """An output folder: refused when it names an existing file, before any work."""
    if Path(text).exists() and not Path(text).is_dir():
        raise argparse.ArgumentTypeError(f"must be a folder, but {text!r} is a file")
    return text


def _envmap(text: str) -> str:
    if text in design.MAPS or (text.lower().endswith(".exr") and Path(text).is_file()):
        return text
    if text.lower().endswith(".exr"):
        raise argparse.ArgumentTypeError(f"no such EXR file: {text}")
    raise argparse.ArgumentTypeError(
        f"unknown map {text!r}; expected one of {', '.join(design.MAPS)} or the path of an "
        ".exr file")


def _experiment(text: str) -> str:
    from . import experiments

    known = experiments.names()
    if text not in known:
        raise argparse.ArgumentTypeError(
            f"invalid choice: {text!r} (choose from {', '.join(known)})")
    return text


def plain(text: str) -> str:
    """``text`` (a docstring) without its reStructuredText markup, for a terminal: roles such
    as :func:`name` become ``name()``, other roles and double backticks their bare text."""
    text = re.sub(r":(?:func|meth):`~?([^`]+?)(?:\(\))?`", r"\1()", text)
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"\1", text)
    return text.replace("``", "")


def list_scenes(_args: argparse.Namespace) -> int:
    print(plain(scenes.__doc__ or "").strip())
    return 0


def experiment(args: argparse.Namespace) -> int:
    from . import experiments

    if args.list or args.name is None:
        for name in experiments.names():
            text = " ".join(plain(experiments.describe(name)).split())
            first = re.split(r"(?<=[a-z0-9)]\.)\s+(?=[A-Z])", text, maxsplit=1)[0]
            print(textwrap.fill(first, width=88, initial_indent=f"{name:<15} ",
                                subsequent_indent=" " * 16))
        return 0 if args.list else 2
    try:
        import matplotlib  # noqa: F401 - only whether it is there
    except ImportError:
        print("viscache experiment: the experiments plot with matplotlib, which is not "
              "installed; install the extra with: pip install 'viscache_rs[experiments]'",
              file=sys.stderr)
        return 2
    client = {None: "serial", "local": None}.get(args.scheduler, args.scheduler)
    ctx = experiments.run(args.name, quick=args.quick, out=args.out, seed=args.seed,
                          threads=args.threads, progress=_bars(args.quiet), client=client)
    print(f"wrote {ctx.out}/ in {ctx.results['seconds']:.1f} s")
    return 0


def sweep(args: argparse.Namespace) -> int:
    """Runs a sweep file's points on Dask and writes the table and the efficiency plot."""
    from .experiments import sweeps

    missing = [m for m in ("distributed", "pandas", "pyarrow", "matplotlib")
               if importlib.util.find_spec(m) is None]
    if missing:
        print(f"viscache sweep: needs {', '.join(missing)}; install the extra with: "
              "pip install 'viscache_rs[sweep]'", file=sys.stderr)
        return 2
    try:
        points = sweeps.load(args.config)
    except (ValueError, TypeError) as e:
        print(f"viscache sweep: {e}", file=sys.stderr)
        return 2
    client = (sweeps.SERIAL if args.serial
              else None if args.scheduler in (None, "local") else args.scheduler)
    t = time.perf_counter()
    table = sweeps.sweep(points, client, workers=args.workers, progress=_bars(args.quiet))
    written = sweeps.write(table, args.out)
    print(sweeps.summary(table))
    print(f"{len(table)} points in {time.perf_counter() - t:.1f} s; wrote "
          f"{', '.join(str(p) for p in written)}")
    return 0


def _sweep_file(text: str) -> str:
    """A sweep file: an existing .json or .toml file (its contents are checked before any
    work by ``sweeps.load``)."""
    if Path(text).suffix.lower() not in (".json", ".toml"):
        raise argparse.ArgumentTypeError(f"expected a .json or .toml file, got {text!r}")
    if not Path(text).is_file():
        raise argparse.ArgumentTypeError(f"no such file: {text}")
    return text


def _scheduler(text: str) -> str:
    if text == "local" or re.fullmatch(r"[a-z]+://\S+", text):
        return text
    raise argparse.ArgumentTypeError(
        f"expected a scheduler's address such as tcp://host:8786 or 'local', got {text!r}")


def main(argv: list[str] | None = None) -> int:
    """Runs the ``viscache`` command with ``argv`` (default: the process's arguments) and
    returns its exit status. Every option is checked by its argparse type or choices before
    any work, against the ranges the library itself checks (``viscache_rs._core.LIMITS``):
    a bad one exits with status 2 and a usage line naming it and what it accepts."""
    args = build_parser().parse_args(argv)
    return args.func(args)


def build_parser() -> argparse.ArgumentParser:
    """The ``viscache`` command's parser, with its subcommands."""
    parser = argparse.ArgumentParser(prog="viscache", description=plain(__doc__ or ""),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    suite = scenes.suite_names()
    spp, threads, seed = _integer("spp"), _integer("threads"), _integer("seed")
    side = _integer("image_side")
    p = sub.add_parser("demo", help="equal-time product sampling vs the cache's control variate",
                       usage="%(prog)s [options]")
    p.add_argument("--scene", default="garage", choices=suite, metavar="SCENE",
                   help=f"one of {', '.join(suite)} (default garage)")
    p.add_argument("--detail", type=_number("detail", open_low=True), default=1.0,
                   help="scene detail (default 1)")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--width", type=side, default=512, help="pixels (default 512)")
    p.add_argument("--height", type=side, default=384, help="pixels (default 384)")
    p.add_argument("--threads", type=threads, default=None, help="default: every core")
    p.add_argument("--spp", type=spp, default=16, help="samples per pixel of the cv render")
    p.add_argument("--resolution", type=_record_resolution, default=None,
                   help="record resolution (2..128; default: the preset's, 64 for auto)")
    p.add_argument("--preset", default="auto", choices=["auto", "low", "medium", "high"])
    p.add_argument("--alpha", type=_alpha, default="estimate",
                   help="control-variate alpha: a number in [0, 2] or 'estimate'")
    p.add_argument("--quiet", action="store_true",
                   help="no progress bars (default: bars when stderr is a terminal)")
    p.add_argument("--out", type=_folder, default="results/demo",
                   help="folder of the three PNGs (created)")
    p.set_defaults(func=demo)
    p = sub.add_parser("experiment", help="run an experiment and write results/NAME/",
                       usage="%(prog)s NAME [options] | --list")
    p.add_argument("name", nargs="?", type=_experiment,
                   help="the experiment (--list shows them)")
    p.add_argument("--list", action="store_true", help="list the experiments")
    p.add_argument("--quick", action="store_true", help="minutes on 2 cores")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--threads", type=threads, default=None, help="default: every core")
    p.add_argument("--quiet", action="store_true",
                   help="no progress bars (default: bars when stderr is a terminal)")
    p.add_argument("--out", type=_folder, default="results",
                   help="parent folder of results/NAME/")
    p.add_argument("--scheduler", type=_scheduler, default=None, metavar="ADDRESS",
                   help="run the sweeps of tradeoff and variance-table on the Dask cluster "
                   "at ADDRESS (tcp://host:port), or 'local' for a new LocalCluster; "
                   "default: in this process")
    p.set_defaults(func=experiment)
    p = sub.add_parser("sweep", help="run a sweep file's points on Dask",
                       usage="%(prog)s CONFIG [options]")
    p.add_argument("config", type=_sweep_file, metavar="CONFIG",
                   help="the sweep file (.json or .toml; README \"Sweeps\")")
    p.add_argument("--scheduler", type=_scheduler, default=None, metavar="ADDRESS",
                   help="an existing cluster's scheduler (tcp://host:port); default: a new "
                   "LocalCluster of one single-threaded worker process per core")
    p.add_argument("--workers", type=_integer("threads"), default=None,
                   help="workers of the new LocalCluster (default: one per core)")
    p.add_argument("--serial", action="store_true",
                   help="run the points one after another in this process, without Dask")
    p.add_argument("--out", type=_folder, default="results/sweep",
                   help="folder of sweep.parquet and efficiency.png (created)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=sweep)
    p = sub.add_parser("preview", help="preview frames of a rotating map from the cached "
                       "transfer, with timings", usage="%(prog)s SCENE [options]")
    p.add_argument("scene", choices=suite, metavar="SCENE", help=f"one of {', '.join(suite)}")
    p.add_argument("--rotate", type=_rotations, default=_rotations("0:360:15"),
                   metavar="A:B:STEP",
                   help="degrees about +y: A, A+STEP, ... below B (default 0:360:15)")
    p.add_argument("--out", type=_folder, default="frames",
                   help="folder of the frames (created)")
    p.add_argument("--width", type=side, default=640, help="pixels (default 640)")
    p.add_argument("--height", type=side, default=480, help="pixels (default 480)")
    p.add_argument("--envmap", type=_envmap, default="scene", metavar="NAME",
                   help=f"the map: {', '.join(design.MAPS)} (viscache_rs.design.MAPS says "
                   "what each is) or the path of an .exr file; default: the scene's own")
    p.add_argument("--basis", default="auto", choices=["auto", "full", "texels", "haar", "sh"],
                   help="of the transfer (default auto: the cheapest to update within 1.25x of the "
                   "least error among those that fit the budget)")
    p.add_argument("--budget-mb", type=_positive(float), default=200.0,
                   help="memory for the transfer in MB (default 200)")
    p.add_argument("--threads", type=threads, default=None, help="default: every core")
    p.add_argument("--quiet", action="store_true",
                   help="no progress bars (default: bars when stderr is a terminal)")
    p.set_defaults(func=preview)
    p = sub.add_parser("scenes", help="list the built-in scenes", usage="%(prog)s")
    p.set_defaults(func=list_scenes)
    return parser


if __name__ == "__main__":
    sys.exit(main())
