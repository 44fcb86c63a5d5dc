"""The ``viscache`` command line.

``viscache demo``   render a built-in scene's first-hit shading (with sun shadows) and print
                    where the time went.
``viscache scenes`` list the built-in scenes.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from . import scenes
from .io import to_srgb8, write_png

SUN_DIRECTION = np.array([0.45, 0.8, 0.4], dtype=np.float32)
SKY_COLOR = np.array([0.55, 0.7, 0.9], dtype=np.float32)


def object_colors(scene) -> np.ndarray:
    """(num_objects, 3) base colour of each object's material."""
    colors = np.zeros((max(scene.num_objects, 1), 3), dtype=np.float32)
    for obj in range(scene.num_objects):
        p = scene.material(obj).params()
        colors[obj] = p["albedo"] if "albedo" in p else np.add(p["kd"], p["ks"])
    return colors


def first_hit_shading(setup, seed: int = 0, threads: int | None = None) -> tuple[np.ndarray, dict]:
    """Albedo x (ambient + sun with a traced shadow ray) at each pixel's first hit.

    Returns the (H, W, 3) float32 image and a dict of timings and ray counts.
    """
    scene, camera = setup.scene, setup.camera
    sun = SUN_DIRECTION / np.linalg.norm(SUN_DIRECTION)
    stats: dict[str, float] = {}

    t = time.perf_counter()
    stats["bvh_build_s"] = scene.build(threads=threads)
    stats["bvh_total_s"] = time.perf_counter() - t

    t = time.perf_counter()
    g = scene.gbuffer(camera, seed=seed, threads=threads)
    stats["gbuffer_s"] = time.perf_counter() - t

    hit = g["object"] >= 0
    pos, nrm = g["position"][hit], g["normal"][hit]
    t = time.perf_counter()
    origins = scene.offset_points(pos, nrm)
    dirs = np.broadcast_to(sun, origins.shape)
    lit = ~scene.occluded(origins, dirs, threads=threads)
    stats["shadow_rays_s"] = time.perf_counter() - t
    stats["shadow_rays"] = int(hit.sum())

    cos = np.clip(nrm @ sun, 0.0, None)
    albedo = object_colors(scene)[g["object"][hit]]
    image = np.empty((camera.height, camera.width, 3), dtype=np.float32)
    image[:] = SKY_COLOR
    image[hit] = albedo * (0.15 + 0.85 * (cos * lit)[:, None])
    rays = camera.width * camera.height + stats["shadow_rays"]
    stats["rays_per_s"] = rays / (stats["gbuffer_s"] + stats["shadow_rays_s"])
    return image, stats


def demo(args: argparse.Namespace) -> int:
    t = time.perf_counter()
    setup = scenes.load(args.scene, detail=args.detail, seed=args.seed)
    generate_s = time.perf_counter() - t
    setup.camera = setup.camera.with_resolution(args.width, args.height)
    image, stats = first_hit_shading(setup, seed=args.seed, threads=args.threads)
    out = write_png(Path(args.out) / f"{args.scene}_first_hit.png", to_srgb8(image))
    scene = setup.scene
    print(f"scene {args.scene}: {scene.num_triangles:,} triangles, {scene.num_objects} objects")
    print(f"{'stage':<22}{'seconds':>10}")
    print(f"{'generate scene':<22}{generate_s:>10.4f}")
    print(f"{'BVH build':<22}{stats['bvh_build_s']:>10.4f}")
    print(f"{'G-buffer':<22}{stats['gbuffer_s']:>10.4f}")
    print(f"{'shadow rays':<22}{stats['shadow_rays_s']:>10.4f}")
    print(f"{setup.camera.width}x{setup.camera.height} pixels, {stats['shadow_rays']:,} shadow "
          f"rays, {stats['rays_per_s'] / 1e6:.2f} Mrays/s")
    print(f"wrote {out}")
    return 0


def list_scenes(_args: argparse.Namespace) -> int:
    print(scenes.__doc__)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="viscache", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("demo", help="first-hit shading of a built-in scene, with timings")
    p.add_argument("--scene", default="garage", choices=scenes.names())
    p.add_argument("--detail", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--width", type=int, default=512)
    p.add_argument("--height", type=int, default=384)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--out", default="results/demo")
    p.set_defaults(func=demo)
    p = sub.add_parser("scenes", help="list the built-in scenes")
    p.set_defaults(func=list_scenes)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
