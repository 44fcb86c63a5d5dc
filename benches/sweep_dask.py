"""A 24-point sweep on a LocalCluster of 2 single-threaded workers against the same points
run one after another in one process (``client="serial"``, one thread per render): the
wall-clock ratio, with and without the cluster's start, beside the machine's load.

    python benches/sweep_dask.py [--workers 2] [--size 128x96] [--spp 64]

The points: garage and cornell, product, mis, bsdf and cv (a medium cache shared by its
points) at three sample counts; each scene's reference (product, 4x the most samples) is
rendered once in both runs.
The two runs must give the same rows (but for their seconds): the bench checks it. Target:
>= 1.8x on 2 cores. The machine may be shared: the 1-minute load average is printed
before and after, and a run on a loaded machine says little: there the workers' CPU
seconds over the wall seconds ("cores obtained") show how much of the 2 cores they got.
"""

from __future__ import annotations

import argparse
import os
import time

from viscache_rs.experiments import sweeps


def points(width: int, height: int, spp: int) -> list[dict]:
    """24 points over two scenes and four methods."""
    out = []
    common = {"width": width, "height": height,
              "reference": {"method": "product", "spp": 4 * spp, "seed": 7}}
    for scene in ("garage", "cornell"):
        for k, n in enumerate((spp // 4, spp // 2, spp)):
            out += [{**common, "scene": scene, "method": "product", "spp": n, "seed": k},
                    {**common, "scene": scene, "method": "mis", "spp": n, "seed": k},
                    {**common, "scene": scene, "method": "bsdf", "spp": n, "seed": k},
                    {**common, "scene": scene, "method": "cv", "spp": n, "seed": k,
                     "cache": {"preset": "medium", "resolution": 32}}]
    return out


def _cpu_seconds() -> float:
    """This process's CPU seconds, all its threads (run on each worker)."""
    return time.process_time()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--size", default="128x96")
    parser.add_argument("--spp", type=int, default=64)
    args = parser.parse_args(argv)
    width, height = (int(v) for v in args.size.split("x"))
    pts = points(width, height, args.spp)
    load_before = os.getloadavg()[0]

    t, cpu = time.perf_counter(), time.process_time()
    serial = sweeps.sweep(pts, sweeps.SERIAL)
    serial_s = time.perf_counter() - t
    serial_cpu = time.process_time() - cpu

    from distributed import Client, LocalCluster

    t = time.perf_counter()
    with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        client.wait_for_workers(args.workers)
        # The workers import the package as this process did before its run: part of the
        # start, not of the sweep.
        client.run(lambda: __import__("viscache_rs.experiments._sweep_tasks"))
        start_s = time.perf_counter() - t
        before = client.run(_cpu_seconds)
        t = time.perf_counter()
        dask = sweeps.sweep(pts, client)
        dask_s = time.perf_counter() - t
        after = client.run(_cpu_seconds)
        dask_cpu = sum(after[w] - before[w] for w in after if w in before)
    keep = [c for c in serial.columns if c not in sweeps.TIMING_COLUMNS]
    same = serial[keep].equals(dask[keep])
    load_after = os.getloadavg()[0]
    print(f"{len(pts)} points at {width}x{height}, {args.spp // 4}..{args.spp} spp, "
          f"{os.cpu_count()} cores")
    print(f"one process, one after another: {serial_s:.2f} s")
    print(f"LocalCluster of {args.workers}: {dask_s:.2f} s (+ {start_s:.2f} s to start)")
    print(f"ratio: {serial_s / dask_s:.2f}x (sweep alone), "
          f"{serial_s / (dask_s + start_s):.2f}x (with the cluster's start); target >= 1.8x")
    print(f"same rows but the seconds: {same}")
    # CPU seconds over wall seconds: the cores each run got; on a shared machine the ratio
    # above is at most the ratio of these.
    print(f"cores obtained: {serial_cpu / serial_s:.2f} (one process), "
          f"{dask_cpu / dask_s:.2f} (workers); CPU seconds {serial_cpu:.1f} and {dask_cpu:.1f}")
    print(f"1-minute load average: {load_before:.2f} before, {load_after:.2f} after")


if __name__ == "__main__":
    main()
