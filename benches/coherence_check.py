"""Does the ``"auto"`` cache's coherence check decide right? Its prediction beside the
measured gain of the records it would build.

Per suite scene, size and spp, with ``vc.render(method="cv")``'s record cap for that spp
(one record per 400 samples, at least the bootstrap's, at most a tenth of the covered
pixels):

- the check's ``predicted_variance_ratio`` and ``predicted_gain`` (a build with a spent
  time budget stops right after the check);
- the same cap's records forced (``check_coherence=False``): the control variate's
  variance on RGB over product sampling's at the same spp, and the measured gain, product
  sampling's variance x seconds over the control variate's with its build.

The check decides right where both gains lie on the same side of 1. One run each; the
table goes to stdout, the rows to ``--out`` (JSON lines).

    python benches/coherence_check.py [--sizes 256x192 640x480] [--spp 10 100]
        [--out coherence.jsonl] [scene ...]
"""

import argparse
import json
import math
import time

import viscache_rs as vc
from viscache_rs.render import record_cap

# A checked build stops at a tenth of the covered pixels, at least 1,024 records
# (`visibility::params::record_cap`); the forced cache is given the same cap.
SHARE_LIMIT, MIN_SHARE_CAP = 0.1, 1024


def forced_cap(scene, pixels, covered, spp):
    """The cap of ``vc.render(method="cv")``'s own build at ``spp``, checked."""
    return min(record_cap(scene, pixels, spp), max(math.ceil(SHARE_LIMIT * covered),
                                                   MIN_SHARE_CAP))


def measure(setup, size, ladder, threads, emit):
    scene = setup.scene
    g = scene.gbuffer(setup.camera.with_resolution(*size), jitter=False, threads=threads)
    kw = dict(threads=threads, progress=False, gbuffer=g)
    # Per-pixel denominators of the relative variance (any fixed image does).
    denominator = vc.render(setup, spp=64, method="product", seed=7, **kw).image
    for spp in ladder:
        cap = forced_cap(scene, size[0] * size[1], g.covered_pixels, spp)
        checked = vc.VisibilityCache(scene, nearest_hits=False, max_records=cap)
        check = checked.build(seed=1, threads=threads, progress=False, gbuffer=g, spp=spp,
                              time_budget=1e-9)
        t = time.perf_counter()
        product = vc.render(setup, spp=spp, method="product", seed=1, **kw)
        product_s = time.perf_counter() - t
        t = time.perf_counter()
        forced = vc.VisibilityCache(scene, nearest_hits=False, check_coherence=False,
                                    max_records=cap)
        forced.build(seed=1, threads=threads, progress=False, gbuffer=g, spp=spp)
        cv = vc.render(setup, spp=spp, method="cv", cache=forced, seed=1, **kw)
        cv_s = time.perf_counter() - t
        var_p = vc.metrics.relative_variance(product.variance, denominator)
        var_cv = vc.metrics.relative_variance(cv.variance, denominator)
        emit(dict(scene=setup.name, size=f"{size[0]}x{size[1]}", spp=spp, cap=cap,
                  records=len(forced), predicted_ratio=check["predicted_variance_ratio"],
                  predicted_gain=check["predicted_gain"], ratio=var_cv / var_p,
                  gain=(var_p * product_s) / (var_cv * cv_s)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--sizes", nargs="+", default=["256x192", "640x480"])
    ap.add_argument("--spp", nargs="+", type=int, default=[10, 100])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    out = open(args.out, "a") if args.out else None
    print("| scene | size | spp | predicted ratio | measured ratio | predicted gain | "
          "measured gain | agree |")
    print("|---|---|---:|---:|---:|---:|---:|---|")
    agree = total = 0

    def emit(row):
        nonlocal agree, total
        if out:
            out.write(json.dumps(row) + "\n")
            out.flush()
        if row["predicted_gain"] is None:  # blind: no ray of the check sees the map
            print(f"| {row['scene']} | {row['size']} | {row['spp']} | blind | "
                  f"{row['ratio']:.3f} | | {row['gain']:.2f} | |", flush=True)
            return
        same = (row["predicted_gain"] >= 1) == (row["gain"] >= 1)
        agree, total = agree + same, total + 1
        print(f"| {row['scene']} | {row['size']} | {row['spp']} | "
              f"{row['predicted_ratio']:.3f} | {row['ratio']:.3f} | "
              f"{row['predicted_gain']:.2f} | {row['gain']:.2f} | "
              f"{'yes' if same else '**no**'} |", flush=True)

    for name in args.scenes or vc.scenes.suite_names():
        setup = vc.scenes.load(name)
        for size in args.sizes:
            w, h = (int(x) for x in size.split("x"))
            measure(setup, (w, h), args.spp, args.threads, emit)
    print(f"\nthe check's decision agrees with the measured gain on {agree} of {total} cases")


if __name__ == "__main__":
    main()
