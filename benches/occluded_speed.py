"""Seconds of scene.occluded on 400k fixed random segments in garden, one thread, counting
off: the unfiltered shadow query's speed, to compare builds before and after a change to
the tracer (run it with each build's interpreter)."""

import time

import numpy as np
import viscache_rs as vc

setup = vc.scenes.load("garden")
sc = setup.scene
lo, hi = np.asarray(sc.bounds[0]), np.asarray(sc.bounds[1])
rng = np.random.default_rng(0)
n = 400_000
o = (lo + (hi - lo) * rng.random((n, 3))).astype(np.float32)
t = (lo + (hi - lo) * rng.random((n, 3))).astype(np.float32)
d = t - o
tmax = np.linalg.norm(d, axis=1).astype(np.float32)
d = (d / tmax[:, None]).astype(np.float32)
sc.counting = False
sc.occluded(o, d, tmax, threads=1)
best = []
for _ in range(7):
    s = time.perf_counter()
    sc.occluded(o, d, tmax, threads=1)
    best.append(time.perf_counter() - s)
print(f"occluded {n} rays, 1 thread: min {min(best):.4f} s median {sorted(best)[3]:.4f} s")
