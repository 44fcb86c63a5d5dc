"""Samples per second and variance of the four direct-lighting methods (issue: baseline
renderer). Renders garage and dynamics at 256 x 192 with 10 spp by each method, two threads,
and prints per method: samples/s, rays/s, the mean per-pixel variance of the mean over all
pixels and over glossy (Phong) pixels, and the ratio of env-only to product variance there.

    pip install ".[experiments]" && python benches/render_methods.py [--spp 10] [--threads 2]
"""

from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np
import viscache_rs as vc

METHODS = ["env", "bsdf", "mis", "product"]


def glossy_mask(setup) -> np.ndarray:
    g = setup.scene.gbuffer(setup.camera, jitter=False)
    scene = setup.scene
    kinds = np.array([scene.material(i).kind == "phong" for i in range(scene.num_objects)])
    obj = g["object"]
    return (obj >= 0) & kinds[np.maximum(obj, 0)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=10)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--width", type=int, default=256)
    ap.add_argument("--height", type=int, default=192)
    ap.add_argument("--out", default="results/render_methods.json")
    args = ap.parse_args()

    rows = []
    for name in ("garage", "dynamics"):
        setup = vc.scenes.load(name)
        setup.camera = setup.camera.with_resolution(args.width, args.height)
        glossy = glossy_mask(setup)
        vc.render(setup, spp=1, method="mis", threads=args.threads, progress=False)  # warm-up
        for method in METHODS:
            r = vc.render(setup, spp=args.spp, method=method, threads=args.threads, progress=False)
            var = vc.metrics.luminance_variance(r.variance)
            row = {
                "scene": name,
                "method": method,
                "spp": r.stats["spp"],
                "seconds": r.stats["seconds"],
                "samples_per_s": r.stats["samples_per_second"],
                "rays_per_s": r.stats["rays_per_second"],
                "variance_all": float(var.mean()),
                "variance_glossy": float(var[glossy].mean()) if glossy.any() else float("nan"),
                "glossy_pixels": int(glossy.sum()),
            }
            rows.append(row)

    header = (f"{'scene':9} {'method':8} {'Msamples/s':>10} {'Mrays/s':>8} "
              f"{'var (all)':>11} {'var (glossy)':>12} {'env/this glossy':>15}")
    print(header)
    for row in rows:
        env = next(r for r in rows if r["scene"] == row["scene"] and r["method"] == "env")
        ratio = env["variance_glossy"] / row["variance_glossy"]
        print(f"{row['scene']:9} {row['method']:8} {row['samples_per_s'] / 1e6:10.3f} "
              f"{row['rays_per_s'] / 1e6:8.2f} {row['variance_all']:11.4g} "
              f"{row['variance_glossy']:12.4g} {ratio:15.2f}")
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
