"""What the control variate costs over product sampling: the constants of the ``"auto"``
cache's coherence check (``rust/src/visibility/cache/coherence.rs``).

For each ``scene:width:height:spp`` this times, best of three on 2 threads, a jittered
``product`` render, the build of a cache capped as ``vc.render(method="cv")`` caps it
(one record per 400 samples, at most a tenth of the covered pixels, the check off so that
it always builds), and a jittered ``cv`` render with that cache; it prints the ratio ``c``
of the two renders' times, the build's share of the product render's time and ``beta``,
one record's build in product samples.

    python benches/cv_costs.py [scene:width:height:spp ...]
"""

import sys
import time

import viscache_rs as vc

DEFAULT_CASES = ("instances:256:192:10", "meshes:256:192:10", "room:256:192:10",
                 "garage:256:192:10", "scales:256:192:10", "instances:256:192:100",
                 "meshes:640:480:10", "hairball:640:480:100")


def best_of(f, n=3):
    """The fastest of ``n`` calls of ``f`` (seconds) and the last call's result."""
    times = []
    for _ in range(n):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return min(times), out


def measure(case):
    """One ``scene:width:height:spp`` case, printed as a line."""
    name, w, h, spp = case.split(":")
    w, h, spp = int(w), int(h), int(spp)
    setup = vc.scenes.load(name)
    g = setup.scene.gbuffer(setup.camera.with_resolution(w, h), jitter=False, threads=2)
    kw = dict(gbuffer=g, spp=spp, jitter=True, progress=False, threads=2)
    t_product, _ = best_of(lambda: vc.render(setup, method="product", **kw))
    cap = min(max(500, w * h * spp // 400), max(1024, g.covered_pixels // 10))

    def build():
        cache = vc.VisibilityCache(setup.scene, check_coherence=False, max_records=cap)
        cache.build(gbuffer=g, progress=False, threads=2)
        return cache

    t_build, cache = best_of(build)
    t_cv, _ = best_of(lambda: vc.render(setup, method="cv", cache=cache, **kw))
    per_sample = t_product / (w * h * spp)
    print(f"{name:10s} {w}x{h} {spp:4d} spp: product {t_product:.3f} s, build "
          f"{t_build:.3f} s ({len(cache)} records), cv {t_cv:.3f} s; "
          f"c = {t_cv / t_product:.2f}, build share {t_build / t_product:.2f}, "
          f"beta = {t_build / len(cache) / per_sample:.0f}", flush=True)


if __name__ == "__main__":
    for case in sys.argv[1:] or DEFAULT_CASES:
        measure(case)
