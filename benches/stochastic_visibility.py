"""relMSE and seconds of method "stochastic" (box proxies, each probability mode) against
exact visibility (method "env", the same light samples) at equal spp on cornell and garden;
the reference is "env" at many spp. Usage: python benches/stochastic_visibility.py [spp]
[reference spp] (defaults 16, 512)."""

import sys
import time

import viscache_rs as vc

W, H = 128, 96
SPP = int(sys.argv[1]) if len(sys.argv) > 1 else 16
REF_SPP = int(sys.argv[2]) if len(sys.argv) > 2 else 512
for name in ["cornell", "garden"]:
    setup = vc.scenes.load(name)
    cam = setup.camera.with_resolution(W, H)
    ref = vc.render(setup, camera=cam, spp=REF_SPP, method="env", seed=99, threads=2,
                    progress=False)
    t = time.perf_counter()
    proxies = vc.Proxies.boxes(setup.scene)
    tb = time.perf_counter() - t
    print(f"{name}: {setup.scene.num_triangles} triangles, {setup.scene.num_objects} objects, "
          f"{proxies.num_triangles} proxy triangles (built in {tb:.3f} s); ref env {REF_SPP} spp")
    runs = [("env", {})] + [("stochastic", dict(proxies=proxies, probabilities=p))
                            for p in ("equal", "optimal", "cost")]
    for method, kw in runs:
        out = vc.render(setup, camera=cam, spp=SPP, method=method, seed=1, threads=2,
                        progress=False, **kw)
        s = out.stats
        e = vc.metrics.relmse(out.image, ref.image)
        sec = s["seconds"]
        label = method if not kw else f"stochastic/{kw['probabilities']}"
        extra = ""
        if kw:
            extra = (f" shadow {s['shadow_rays']} proxy {s['proxy_rays']} scene {s['scene_rays']}"
                     f" (split {s['split_rays']}, probes {s['probe_rays']}) terms {s['terms']}"
                     f" inside {s['inside_points']} scene nodes {s['scene_nodes']} tris"
                     f" {s['scene_triangle_tests']} proxy nodes {s['proxy_nodes']} tris"
                     f" {s['proxy_triangle_tests']}")
        else:
            extra = f" shadow {s['shadow_rays']}"
        print(f"  {label:20s} relMSE {e:.4g} seconds {sec:.3f} eff {1/(e*sec):.3g}{extra}")
