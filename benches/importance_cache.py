"""Method "importance_cache" against the exact sum on cornell with ~10k importance-driven
VPLs (``VPLs.trace(setup, 10000, importance=True)``), 64x48 through the pixels' centres
(``jitter=False``, so every method shades the same points and the error is the light
sampling's alone): relMSE at 64 spp with shadow rays per sample and seconds, for
``vpl_sampled`` uniform and power, each row alone, balance, and alpha-max over a sweep of
``lam`` and ``alpha``; the build's microseconds per record-light pair and bytes per light
and record. ``python benches/importance_cache.py``."""

from __future__ import annotations

import json

import viscache_rs as vc
from viscache_rs.metrics import relmse

SPP = 64


def main() -> None:
    setup = vc.scenes.load("cornell")
    cam = setup.camera.with_resolution(64, 48)
    vpls = vc.VPLs.trace(setup, 10000, importance=True, threads=2)
    ref = vc.render(setup, camera=cam, method="vpl", vpls=vpls, spp=1, threads=2, jitter=False)
    print("vpls", len(vpls), "exact seconds", round(ref.stats["seconds"], 3))

    def run(label: str, **kw) -> None:
        r = vc.render(setup, camera=cam, vpls=vpls, spp=SPP, threads=2, seed=1, jitter=False,
                      progress=False, **kw)
        samples = cam.width * cam.height * SPP
        print(label, json.dumps({"relmse": relmse(r.image, ref.image),
                                 "seconds": round(r.stats["seconds"], 3),
                                 "rays_per_sample": round(r.stats["shadow_rays"] / samples, 2)}))

    for sampling in ["uniform", "power"]:
        run(sampling, method="vpl_sampled", sampling=sampling, vpl_samples=16)
    cache = vc.ImportanceCache(setup.scene, vpls)
    rep = cache.build(cam, threads=2, progress=False)
    print("build", json.dumps({k: rep[k] for k in ("records", "pairs", "rays", "seconds",
                                                   "us_per_pair")}),
          "bytes per light and record", round(cache.memory_bytes() / (len(cache) * len(vpls)), 2))
    for combine in ["balance", "F", "U", "B", "C"]:
        run(combine, method="importance_cache", cache=cache, combine=combine, vpl_samples=4)
    for lam in [0.0, 1.0, 4.0]:
        for alpha in [(0.5, 0.5, 0.5, 1.0), (1.0, 1.0, 1.0, 1.0), (0.2, 0.2, 0.2, 1.0),
                      (0.1, 0.5, 0.5, 1.0)]:
            run(f"alpha_max lam={lam} alpha={alpha}", method="importance_cache", cache=cache,
                combine="alpha_max", vpl_samples=4, lam=lam, alpha=alpha)


if __name__ == "__main__":
    main()
