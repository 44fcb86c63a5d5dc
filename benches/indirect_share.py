"""Share of each image's energy that is indirect light, for the setups of
``vc.scenes.indirect_names()`` (and any ``name[:variant]`` given on the command line).

The share is ``mean(indirect) / mean(total)``: image means (over pixels and channels) of
``vc.render(setup, camera 128x96, method="path", bounces=B, direct=False)`` and of the same
render with ``direct=True``, two independent renders (seeds 0 and 1). Its standard error
comes from the renders' per-pixel variances (pixels are independent; the channel mean's
standard error is bounded by the mean of the channels', so it is conservative).

    python benches/indirect_share.py [--spp 256] [--bounces 3] [--size 128x96] [name[:variant] ...]
"""

import argparse
import time

import numpy as np
import viscache_rs as vc


def image_mean(result):
    """Mean of the image over pixels and channels, and its standard error."""
    img = np.asarray(result.image, np.float64)[..., :3]
    se = np.sqrt(np.asarray(result.variance, np.float64)[..., :3]).mean(axis=2)
    return img.mean(), np.sqrt((se ** 2).sum()) / se.size


def indirect_share(setup, spp, bounces=3, size=(128, 96), threads=None):
    """(share, its standard error, total mean, indirect mean, seconds)."""
    camera = setup.camera.with_resolution(*size)
    t = time.perf_counter()
    kw = dict(camera=camera, method="path", bounces=bounces, spp=spp, threads=threads,
              progress=False)
    total, se_t = image_mean(vc.render(setup, direct=True, seed=0, **kw))
    ind, se_i = image_mean(vc.render(setup, direct=False, seed=1, **kw))
    share = ind / total
    se = share * np.hypot(se_i / ind, se_t / total)
    return share, se, total, ind, time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--bounces", type=int, default=3)
    ap.add_argument("--size", default="128x96")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("setups", nargs="*")
    a = ap.parse_args()
    size = tuple(int(x) for x in a.size.split("x"))
    specs = ([tuple(s.split(":")) if ":" in s else (s, None) for s in a.setups]
             or vc.scenes.indirect_names())
    print("| scene | variant | indirect share | SE | total mean | indirect mean | seconds |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name, variant in specs:
        setup = vc.scenes.load(name, variant=variant)
        share, se, total, ind, secs = indirect_share(setup, a.spp, a.bounces, size, a.threads)
        print(f"| {name} | {variant or '(default)'} | {share:.3f} | {se:.4f} | {total:.4g} "
              f"| {ind:.4g} | {secs:.1f} |", flush=True)


if __name__ == "__main__":
    main()
