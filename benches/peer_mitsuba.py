"""Equal-time renders against Mitsuba 3, the renderer a user would pick instead.

Every scene is exported with ``viscache_rs.mitsuba`` (the same meshes, materials, env map,
area lights, camera and box filter) and rendered by Mitsuba's ``direct`` integrator (one
emitter and one BSDF sample per pixel sample, MIS, independent sampler) in passes of 8 spp
until the budget is spent, and by ours with ``vc.render(..., time_budget=b)`` (method
``cv`` builds its cache inside the budget). Both are timed as whole calls after a warm-up
(Mitsuba compiles a kernel on its first render; we build per-process tables).

The reference is Mitsuba at ``--ref-spp`` in 16 independent chunks, whose spread gives the
per-pixel variance that ``relmse`` subtracts. Reported per scene, budget and method: spp
reached (ours: the mean over pixels; adaptive by default under a budget), samples per
second, wall seconds, relMSE on RGB and its ratio to Mitsuba's,
efficiency 1/(relMSE s), and the ratio of image means with its z-score against the
reference (agreement within 4 SE cross-validates the two renderers). The worst scene is
printed beside the geometric mean.

    python benches/peer_mitsuba.py                       # 160x120, budgets 1 3 10 s
    python benches/peer_mitsuba.py --quick               # 1 s only, fewer scenes
    python benches/peer_mitsuba.py --scenes garage cornell --budgets 1 3 --out peer.json

Needs ``pip install mitsuba`` and, for the default ``llvm_ad_rgb`` variant, LLVM 19 (Debian's
``libllvm19``: ``scripts/install-llvm.sh`` installs it and prints the ``DRJIT_LIBLLVM_PATH``
to set if an older one is found first). Without it the script says so on stderr and falls
back to ``scalar_rgb`` (the JSON's ``variant`` records the one used).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np
import viscache_rs as vc
from viscache_rs import metrics

DEFAULT_SCENES = ["garage", "garden", "dynamics", "cornell"]
REF_CHUNKS = 16
MITSUBA_PASS_SPP = 8
SETTLE_SECONDS = 0.3


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", nargs="*", default=None,
                   help="scene names (default: every vc.scenes.suite_names() scene, or the "
                        "built-ins)")
    p.add_argument("--budgets", nargs="*", type=float, default=[1.0, 3.0, 10.0])
    p.add_argument("--methods", nargs="*", default=["product", "cv"],
                   help="ours; a method may take light draws per sample as 'product:4'")
    p.add_argument("--size", default="160x120", help="WxH")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--ref-spp", type=int, default=2048)
    p.add_argument("--variant", default="llvm_ad_rgb")
    p.add_argument("--equirect-width", type=int, default=None,
                   help="width of the env map's lat-long export (default: "
                        "vc.mitsuba.equirect_width_for the map)")
    p.add_argument("--quick", action="store_true", help="1 s budgets, 512-spp references")
    p.add_argument("--out", default=None, help="write the figures as JSON here")
    return p.parse_args(argv)


def default_scenes() -> list[str]:
    names = getattr(vc.scenes, "suite_names", None)
    return list(names()) if names is not None else list(vc.scenes.names())


def load_setup(name: str):
    return vc.scenes.load(name)


def settle() -> None:
    """Both renderers' thread pools spin for a moment after a render; a pause before each
    timed call keeps one from slowing the other (measured: 20% more CPU time for a render
    started right after Mitsuba's)."""
    time.sleep(SETTLE_SECONDS)


def mitsuba_equal_time(ms, budget: float, seed0: int):
    """Passes of 8 spp until ``budget`` seconds are spent; the mean image, its per-pixel
    variance of the mean (from the passes), spp and seconds."""
    settle()
    start = time.perf_counter()
    passes = []
    while True:
        passes.append(vc.mitsuba.render(ms, MITSUBA_PASS_SPP, seed=seed0 + len(passes)))
        if time.perf_counter() - start >= budget:
            break
    seconds = time.perf_counter() - start
    stack = np.stack(passes)
    mean = stack.mean(axis=0)
    var = stack.var(axis=0, ddof=1) / len(passes) if len(passes) > 1 else np.full_like(
        mean, np.inf)
    return mean, var, MITSUBA_PASS_SPP * len(passes), seconds


def method_args(method: str) -> dict:
    """``vc.render`` keywords of a ``--methods`` entry: ``"cv"`` (the defaults, which
    choose the light draws per sample from the view), ``"cv:4"`` (4 light draws per
    sample), ``"cv:even"`` (every pixel the same samples, not adaptive) or
    ``"cv:4:even"``."""
    name, *options = method.split(":")
    args: dict = {"method": name}
    for option in options:
        if option == "even":
            args["adaptive"] = False
        else:
            args["light_samples"] = int(option)
    return args


def ours_equal_time(setup, camera, method: str, budget: float, threads: int, seed: int):
    settle()
    start = time.perf_counter()
    r = vc.render(setup, camera=camera, time_budget=budget, threads=threads,
                  progress=False, seed=seed, **method_args(method))
    return r, time.perf_counter() - start


def choose_variant(requested: str) -> str:
    """``requested``, or ``scalar_rgb`` if it is an LLVM variant and LLVM cannot render
    here (choosing it would abort this process): said on stderr, since Mitsuba's times are
    then those of its slow scalar variant and the equal-time comparison favours us."""
    if not requested.startswith("llvm_") or vc.mitsuba.llvm_available():
        return requested
    print(f"# FALLBACK: Mitsuba's {requested} variant cannot render here (it needs LLVM 19, "
          "Debian's libllvm19: scripts/install-llvm.sh, then DRJIT_LIBLLVM_PATH as it "
          "prints); using scalar_rgb, far slower, so Mitsuba's figures below are NOT its "
          "fast ones", file=sys.stderr)
    return "scalar_rgb"


def mean_z(image, variance, ref, ref_var):
    """Ratio of image means and its z-score (the SEs of both means combined)."""
    keep = np.isfinite(ref) & np.isfinite(variance)
    n = keep.sum()
    diff = image[keep].mean() - ref[keep].mean()
    se = math.sqrt(variance[keep].sum() + ref_var[keep].sum()) / n
    return float(image[keep].mean() / ref[keep].mean()), float(diff / se) if se > 0 else 0.0


def main(argv=None) -> int:
    args = parse_args(argv)
    import drjit as dr
    import mitsuba as mi

    variant = choose_variant(args.variant)
    mi.set_variant(variant)
    dr.set_thread_count(args.threads)
    width, height = (int(v) for v in args.size.lower().split("x"))
    budgets = [1.0] if args.quick else args.budgets
    ref_spp = 512 if args.quick else args.ref_spp
    scenes = args.scenes or (DEFAULT_SCENES if args.quick else default_scenes())
    rows = []
    print(f"# our kernels: {vc.testing.simd_level()}", file=sys.stderr)
    for name in scenes:
        setup = load_setup(name)
        cam = setup.camera.with_resolution(width, height)
        setup.scene.build(threads=args.threads)
        ms = vc.mitsuba.load(setup, camera=cam, equirect_width=args.equirect_width)
        for k in range(2):  # warm-up: Mitsuba compiles its kernel, we build tables
            vc.mitsuba.render(ms, MITSUBA_PASS_SPP, seed=10_000 + k)
        for m in args.methods:
            vc.render(setup, camera=cam, spp=1, threads=args.threads, progress=False,
                      **method_args(m))
        t = time.perf_counter()
        chunks = np.stack([vc.mitsuba.render(ms, max(1, ref_spp // REF_CHUNKS),
                                             seed=20_000 + k) for k in range(REF_CHUNKS)])
        ref = chunks.mean(axis=0)
        ref_var = chunks.var(axis=0, ddof=1) / REF_CHUNKS
        print(f"# {name}: reference {ref_spp} spp in {time.perf_counter() - t:.1f} s",
              file=sys.stderr)
        for b in budgets:
            img, var, spp, sec = mitsuba_equal_time(ms, b, seed0=30_000)
            e_mi = metrics.relmse(img, ref, ref_var)
            ratio, z = mean_z(img, var, ref, ref_var)
            rows.append({"scene": name, "budget": b, "method": "mitsuba", "spp": spp,
                         "seconds": sec, "samples_per_second": spp * width * height / sec,
                         "relmse": e_mi, "relmse_per_channel":
                             metrics.relmse_per_channel(img, ref, ref_var).tolist(),
                         "ratio_to_mitsuba": 1.0,
                         "efficiency": metrics.efficiency(e_mi, sec),
                         "mean_ratio": ratio, "mean_z": z})
            for m in args.methods:
                r, sec = ours_equal_time(setup, cam, m, b, args.threads, seed=1)
                e = metrics.relmse(r.image, ref, ref_var)
                ratio, z = mean_z(r.image.astype(float), r.variance.astype(float), ref,
                                  ref_var)
                rows.append({"scene": name, "budget": b, "method": m,
                             "spp": round(r.stats["mean_spp"], 1), "seconds": sec,
                             "samples_per_second": r.stats["samples"] / sec,
                             "relmse": e, "relmse_per_channel":
                                 metrics.relmse_per_channel(r.image, ref, ref_var).tolist(),
                             "ratio_to_mitsuba": e / e_mi,
                             "efficiency": metrics.efficiency(e, sec),
                             "mean_ratio": ratio, "mean_z": z,
                             "cache_seconds": r.stats.get("cache_seconds", 0.0),
                             "cache_records": r.stats.get("cache_records"),
                             "cache_planned_spp": r.stats.get("cache_planned_spp"),
                             "cache_predicted_gain": r.stats.get("cache_predicted_gain")})
            print_rows([r for r in rows if r["scene"] == name and r["budget"] == b])
    print_summary(rows, budgets, args.methods)
    if variant != args.variant:
        print(f"\nMitsuba ran as {variant}, NOT {args.variant} (no LLVM 19 here): its times "
              "are its slow ones.")
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"size": [width, height], "threads": args.threads,
                       "ref_spp": ref_spp, "variant": variant,
                       "simd_level": vc.testing.simd_level(), "rows": rows}, f, indent=1)
    return 0


def print_rows(rows) -> None:
    for r in rows:
        print(f"| {r['scene']} | {r['budget']:g} s | {r['method']} | {r['spp']} | "
              f"{r['samples_per_second'] / 1e6:.2f} M/s | {r['seconds']:.2f} | "
              f"{r['relmse']:.3e} | **{r['ratio_to_mitsuba']:.2f}** | "
              f"{r['mean_ratio']:.4f} ({r['mean_z']:+.1f} SE) |", flush=True)


def print_summary(rows, budgets, methods) -> None:
    print("\n| method | budget | geomean ratio to Mitsuba | worst scene (ratio) |")
    print("|---|---|---:|---|")
    for m in methods:
        for b in budgets:
            ratios = {r["scene"]: r["ratio_to_mitsuba"] for r in rows
                      if r["method"] == m and r["budget"] == b}
            if ratios:
                s = metrics.worst_and_mean(ratios)
                print(f"| {m} | {b:g} s | {s['geomean']:.2f} | {s['worst']} "
                      f"({s['worst_value']:.2f}) |")
    best = {}
    for r in rows:
        if r["method"] in methods:
            key = (r["scene"], r["budget"])
            best[key] = min(best.get(key, math.inf), r["ratio_to_mitsuba"])
    for b in budgets:
        ratios = {s: v for (s, bb), v in best.items() if bb == b}
        if ratios:
            s = metrics.worst_and_mean(ratios)
            print(f"| best of ours | {b:g} s | {s['geomean']:.2f} | {s['worst']} "
                  f"({s['worst_value']:.2f}) |")


if __name__ == "__main__":
    sys.exit(main())
