"""One process's worth of rendering, for whole-process timings of two builds against each
other (alternate the two, pair the runs, take the median ratio): loads a built-in scene,
then renders it ``--repeats`` times at its default 256x192 with ``method``.

    python benches/render_process.py garage product
    python benches/render_process.py garage cv       # a "medium" cache built first
    python benches/render_process.py garage path     # one bounce
    python benches/render_process.py garage vpl      # 2 spp over 4096 VPLs traced per render
"""

from __future__ import annotations

import argparse

import viscache_rs as vc


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", choices=vc.scenes.names())
    parser.add_argument("method", choices=[m["name"] for m in vc.methods()])
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    setup = vc.scenes.load(args.scene)
    kw: dict = {"spp": args.spp}
    if args.method == "path":
        kw["bounces"] = 1
    if args.method == "cv":
        cache = vc.VisibilityCache(setup.scene, preset="medium")
        cache.build(setup.camera, seed=0, progress=False)
        kw["cache"] = cache
    if args.method.startswith("vpl"):
        kw["spp"] = 2
    for _ in range(args.repeats):
        vc.render(setup, method=args.method, seed=0, progress=False, **kw)


if __name__ == "__main__":
    main()
