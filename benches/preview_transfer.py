"""The lighting preview's cached transfer against the direct preview, per suite scene.

Speed at 640x480 (the issue's size): the default ``"auto"`` cache built for the view (the
``"medium"`` preset's where the default keeps no record),
``LightingPreview.prepare(cache, envmap)`` with its defaults (``basis="auto"``, 200 MB),
then the median and worst milliseconds of ``render(cache, map, rotation=deg)`` over twelve
changes (rotations and swaps), against one ``render(..., direct=True)``.

Error at ``--size`` (160x120 by default; the budget scaled by the pixel count, so each
pixel keeps what it keeps at 640x480): relMSE on RGB (``vc.metrics.relmse``) and the
relative error of the image mean, against a ``--spp`` product render without jitter (the
preview's pixel centres) under the same lighting, its variance taken out of the relMSE
(``vc.metrics.relmse(image, reference, reference_variance)``): the scene's map, the map
turned by 45° and 135° about +y, and a sun-and-sky map. The direct preview sees the turned map
(``EnvMap.rotated``); the transfers get ``rotation=``: ``auto`` (the default),
``nearest`` (each pixel's heaviest record only: CAM08's blotchy preview) and each basis
forced (``haar``, ``sh``, ``texels``) within the same bytes per pixel.

    python benches/preview_transfer.py [--size 160x120] [--spp 256] [scene ...]
"""

import argparse
import statistics
import time

import numpy as np
import viscache_rs as vc

SKY = dict(sun_dir=(0.4, 0.6, -0.5), sun_radiance=(40000.0, 38000.0, 34000.0), sun_angle=1.0)
BUDGET_MB = 200.0


def lightings(setup):
    """(name, map for the direct preview and the reference, map and rotation for the
    transfer)."""
    env = setup.envmap
    sky = vc.envmaps.sky(**SKY)
    return [("map", env, env, None),
            ("45°", env.rotated(45.0), env, 45.0),
            ("135°", env.rotated(135.0), env, 135.0),
            ("sky", sky, sky, None)]


def build_cache(setup, camera, threads=None):
    """The default cache for ``camera``; where its coherence check turns every record away
    (garden, hairball, strands: the control variate would not help there) the preview
    has nothing to show, so the ``"medium"`` preset's records instead."""
    cache = vc.VisibilityCache(setup.scene)
    cache.build(camera, progress=False, threads=threads)
    if len(cache) == 0:
        cache = vc.VisibilityCache(setup.scene, preset="medium")
        cache.build(camera, progress=False, threads=threads)
    return cache


def speed(setup, threads=None):
    cam = setup.camera.with_resolution(640, 480)
    cache = build_cache(setup, cam, threads)
    view = vc.LightingPreview(setup.scene, cam, threads=threads)
    t = time.perf_counter()
    view.render(cache, setup.envmap, direct=True, threads=threads)
    direct = time.perf_counter() - t
    info = view.prepare(cache, setup.envmap, threads=threads)
    sky = vc.envmaps.sky(**SKY)
    times = []
    for k in range(12):
        env = sky if k % 4 == 3 else setup.envmap
        t = time.perf_counter()
        view.render(cache, env, rotation=15.0 * k, threads=threads)
        times.append(time.perf_counter() - t)
    return dict(records=len(cache), direct_ms=1e3 * direct, info=info,
                median_ms=1e3 * statistics.median(times), max_ms=1e3 * max(times))


def errors(setup, size, spp, threads=None):
    cam = setup.camera.with_resolution(*size)
    cache = build_cache(setup, cam, threads)
    budget = BUDGET_MB * size[0] * size[1] / (640 * 480)
    views = {}
    for name, kw in (("auto", {}), ("nearest", dict(nearest=True)), ("haar", dict(basis="haar")),
                     ("sh", dict(basis="sh")), ("texels", dict(basis="texels"))):
        views[name] = vc.LightingPreview(setup.scene, cam, threads=threads)
        info = views[name].prepare(cache, setup.envmap, budget_mb=budget, threads=threads, **kw)
        if name == "auto":
            auto = info
    out = {}
    for name, env, base, rotation in lightings(setup):
        r = vc.render(setup, camera=cam, spp=spp, method="product", envmap=env,
                      jitter=False, progress=False, threads=threads)
        ref, ref_var = r.image, r.variance
        imgs = dict(direct=views["auto"].render(cache, env, direct=True, threads=threads))
        for k, view in views.items():
            imgs[k] = view.render(cache, base, rotation=rotation, threads=threads)
        out[name] = {k: (vc.metrics.relmse(img, ref, ref_var), img.mean() / ref.mean() - 1.0)
                     for k, img in imgs.items()}
    return auto, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--no-speed", action="store_true", help="skip the 640x480 timings")
    ap.add_argument("--no-errors", action="store_true", help="skip the error table")
    ap.add_argument("scenes", nargs="*")
    a = ap.parse_args()
    size = tuple(int(x) for x in a.size.split("x"))
    names = a.scenes or vc.scenes.suite_names()
    if not a.no_speed:
        speed_table(names, a.threads)
    if not a.no_errors:
        error_table(names, size, a.spp, a.threads)


def speed_table(names, threads):
    print("## Speed at 640x480 (ms per lighting change after prepare)\n")
    print("| scene | records | basis | prepare s | MB | median ms | max ms | direct ms |")
    print("|---|---:|---|---:|---:|---:|---:|---:|")
    worst_ms = []
    for name in names:
        s = speed(vc.scenes.load(name), threads)
        i = s["info"]
        basis = i["basis"] + str(i.get("terms", i.get("order", i.get("basis_level"))))
        worst_ms.append((s["max_ms"], name))
        print(f"| {name} | {s['records']} | {basis} | {i['seconds']:.2f} | {i['bytes'] / 1e6:.0f} "
              f"| {s['median_ms']:.1f} | {s['max_ms']:.1f} | {s['direct_ms']:.0f} |", flush=True)
    print(f"\nworst max: {max(worst_ms)[0]:.1f} ms ({max(worst_ms)[1]})\n")


def error_table(names, size, spp, threads):
    print(f"## Error at {size[0]}x{size[1]} against a {spp}-spp product render "
          "(relMSE; mean error in parentheses)\n")
    cols = ("direct", "auto", "nearest", "haar", "sh", "texels")
    print("| scene | lighting | auto basis | " + " | ".join(cols) + " | auto / direct |")
    print("|---|---|---|" + "---:|" * (len(cols) + 1))
    ratios = []
    for name in names:
        setup = vc.scenes.load(name)
        info, out = errors(setup, size, spp, threads)
        if info["pixels"] == 0:
            print(f"| {name} | no pixel sees the map (a closed room lit by its area light) |")
            continue
        basis = info["basis"] + str(info.get("terms", info.get("order", info.get("basis_level"))))
        for light, e in out.items():
            r = e["auto"][0] / e["direct"][0]
            ratios.append((r, f"{name} {light}"))
            cells = " | ".join(f"{e[k][0]:.4f} ({e[k][1]:+.1%})" for k in cols)
            print(f"| {name} | {light} | {basis} | {cells} | {r:.2f} |", flush=True)
    # A relMSE below the reference's own noise comes out negative: such ratios enter the
    # geometric mean as 0.01, and are counted.
    floor = 1e-2
    geo = float(np.exp(np.mean([np.log(max(r, floor)) for r, _ in ratios])))
    worst = max(ratios)
    print(f"\nauto transfer / direct relMSE: geometric mean {geo:.3f} (ratios below {floor} "
          f"as {floor}: {sum(r < floor for r, _ in ratios)}), worst {worst[0]:.3f} "
          f"({worst[1]}), {sum(r <= 1.0 for r, _ in ratios)}/{len(ratios)} at most 1")


if __name__ == "__main__":
    main()
