"""Per-channel variance ratios of the control variate with each scene's map in colour and
turned grey (every texel its luminance): which share of a channel's ratio is the records'
visibility mismatch and which the map's colour.

    python benches/grey_map_channels.py meshes scales dynamics [--size 256 192] [--spp 10]

Prints cv / product variance per RGB channel at the defaults (``method="cv"`` builds its
``"auto"`` cache), the mean over ``--seeds`` seeds.
"""

from __future__ import annotations

import argparse

import numpy as np
import viscache_rs as vc


def grey(env: vc.EnvMap) -> vc.EnvMap:
    """The map with every texel's RGB set to its luminance."""
    lum = vc.metrics.luminance(env.texels()).astype(np.float32)
    return vc.EnvMap.from_octahedral(np.repeat(lum[..., None], 3, axis=-1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", default=["meshes", "scales", "dynamics"])
    ap.add_argument("--size", nargs=2, type=int, default=(256, 192))
    ap.add_argument("--spp", type=int, default=10)
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    print("| scene | map | R | G | B |\n|---|---|---:|---:|---:|")
    for name in args.scenes:
        setup = vc.scenes.load(name)
        cam = setup.camera.with_resolution(*args.size)
        for label, env in (("colour", setup.envmap), ("grey", grey(setup.envmap))):
            ratios = []
            for seed in range(args.seeds):
                cv = vc.render(setup, cam, spp=args.spp, method="cv", envmap=env,
                               progress=False, seed=seed)
                product = vc.render(setup, cam, spp=args.spp, method="product", envmap=env,
                                    progress=False, seed=seed + 100)
                ratios.append(vc.metrics.variance_ratio(cv.variance, product.variance)[0])
            r, g, b = np.mean(ratios, axis=0)
            print(f"| {name} | {label} | {r:.3f} | {g:.3f} | {b:.3f} |", flush=True)


if __name__ == "__main__":
    main()
