"""Times the same rays through viscache_rs and Embree (embreex) at equal threads and checks
that the answers agree.

Workloads (identical rays for both, from ``viscache_rs.testing``):
  incoherent  2^20 rays from points on the ground, directions uniform on the hemisphere;
  bundles     1000 ground points x 1024 stratified hemisphere directions, point after point
              (how visibility records are built);
  shading     the view's jittered first hits at 160x120, 32 passes in pixel order, one
              cosine-weighted direction each (what a render shades with);
  camera      closest hits, not occlusion: the view's jittered camera rays at 160x120,
              16 passes (``Camera.rays``), through ``Scene.intersect`` (which also returns
              hit points and normals) and embreex's ``DISTANCE`` query; answers agree
              where both miss or the distances agree to 1e-3 relative.
  pixels      the same rays pixel after pixel, each pixel's 16 together: the order in
              which a jittered render traces its samples' primary rays (as packets).

Equal threads. ``EmbreeScene.run`` holds the GIL, so Python threads do not run Embree in
parallel; here Embree runs in worker processes instead, each with its own ``EmbreeScene``
(``robust=False``) built over the same triangles and holding its share of every workload's
rays: chunks of 4096 consecutive rays dealt out in turn, so that each share keeps the rays'
order within a chunk and the shares cost alike. A timing starts when every participating
process is built, warmed and past a shared barrier, and ends when the last one is done
(``time.perf_counter`` is the system's monotonic clock, the same in every process). "1
thread" is one worker tracing all the rays against ``Scene.occluded``/``intersect`` with
``threads=1``; "2 threads" is one worker per thread against ``threads=2``.

The four (ours 1, Embree 1, ours 2, Embree 2) are timed in turn within each repeat, so a
drift of the machine's speed hits all alike; each repeat gives a ratio of speeds (> 1: we
are faster) at 1 and at 2 threads, and the median over the repeats is reported with its
least and greatest. Each scene's line also says how many cores other programs kept busy
while it ran (from /proc/stat, less this script's processes).

Without ``--scenes`` every scene of the benchmark suite runs (``vc.scenes.suite_names()``,
the real meshes included when found), and the worst scene is printed beside the geometric
mean of each workload's ratios. ``--quick`` runs two small scenes on smaller workloads in
well under a minute (a smoke test, not a figure to quote).

    python benches/peer_embree.py [--scenes garden cornell] [--repeats 5] [--quick]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import viscache_rs as vc

CHUNK = 4096
"""Rays per chunk dealt to a worker process (the shares interleave by chunks)."""


def timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def interleaved_times(fns: dict, repeats: int, min_seconds: float = 0.05) -> dict:
    """Seconds per call of each of ``fns``, ``repeats`` times, the functions run in turn
    within a repeat. Each function returns its own seconds for ``calls`` calls (so that a
    function timed elsewhere, in worker processes, can say how long it took). A timing
    spans enough calls (the same count for every function) that the slowest function's
    takes ``min_seconds``: a single call of 10 ms is at the mercy of a neighbour's burst
    on this machine, and its ratios then spread by 2x."""
    warm = [fn(1) for fn in fns.values()]
    calls = max(1, int(np.ceil(min_seconds / max(max(warm), 1e-9))))
    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            times[name].append(fn(calls) / calls)
    return times


# ---------------------------------------------------------------- Embree worker processes


def share_index(n: int, part: int, parts: int) -> np.ndarray:
    """Indices of the rays of worker ``part`` of ``parts``: chunks part, part + parts, ..."""
    starts = np.arange(part * CHUNK, n, parts * CHUNK)
    if len(starts) == 0:
        return np.zeros(0, np.int64)
    return np.concatenate([np.arange(s, min(s + CHUNK, n)) for s in starts])


def embree_query(es, origins, dirs, query: str) -> np.ndarray:
    if len(origins) == 0:
        return np.zeros(0, np.float32 if query == "DISTANCE" else np.int32)
    return es.run(origins, dirs, None, query)


def worker(conn, barrier) -> None:
    """One Embree process: builds a scene on ``load``, keeps rays on ``rays``, and on
    ``time`` waits at the barrier and traces its rays ``calls`` times, sending back when it
    started and ended."""
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh

    es, rays = None, {}
    while True:
        msg = conn.recv()
        op = msg[0]
        if op == "load":
            es, rays = None, {}
            es = rtcs.EmbreeScene(robust=False)
            TriangleMesh(es, msg[1])
            es.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32), query="OCCLUDED")
            conn.send("built")
        elif op == "rays":
            _, key, origins, dirs = msg
            rays[key] = (origins, dirs)
            conn.send("ok")
        elif op == "time":
            _, key, query, calls = msg
            origins, dirs = rays.get(key, (np.zeros((0, 3), np.float32),) * 2)
            barrier.wait()
            t0 = time.perf_counter()
            for _ in range(calls):
                embree_query(es, origins, dirs, query)
            conn.send((t0, time.perf_counter()))
        elif op == "answer":
            _, key, query = msg
            conn.send(embree_query(es, *rays[key], query))
        elif op == "cpu":
            t = os.times()
            conn.send(t.user + t.system)
        elif op == "stop":
            return


class EmbreePool:
    """``parts`` worker processes, each with its own Embree scene (``robust=False``)."""

    def __init__(self, parts: int = 2):
        ctx = mp.get_context("spawn")
        self.parts = parts
        self.barrier = ctx.Barrier(parts + 1)
        self.conns, self.procs = [], []
        for _ in range(parts):
            mine, theirs = ctx.Pipe()
            p = ctx.Process(target=worker, args=(theirs, self.barrier), daemon=True)
            p.start()
            self.conns.append(mine)
            self.procs.append(p)

    def _all(self, msgs) -> list:
        for c, m in zip(self.conns, msgs, strict=True):
            c.send(m)
        return [c.recv() for c in self.conns]

    def load(self, triangles: np.ndarray) -> float:
        """Builds every worker's scene; seconds until the last is built and warmed."""
        t = time.perf_counter()
        self._all([("load", triangles)] * self.parts)
        return time.perf_counter() - t

    def set_rays(self, name: str, origins: np.ndarray, dirs: np.ndarray) -> None:
        """Worker 0 keeps all the rays (for one thread); each worker its share."""
        n = len(origins)
        self.conns[0].send(("rays", (name, 1), origins, dirs))
        self.conns[0].recv()
        for k, c in enumerate(self.conns):
            idx = share_index(n, k, self.parts)
            c.send(("rays", (name, self.parts), np.ascontiguousarray(origins[idx]),
                    np.ascontiguousarray(dirs[idx])))
            c.recv()

    def time(self, name: str, query: str, threads: int, calls: int) -> float:
        """Seconds from the barrier to the last participating worker done; workers beyond
        ``threads`` pass the barrier with no rays."""
        key = (name, threads)
        for k, c in enumerate(self.conns):
            c.send(("time", key if k < threads else ("idle",), query, calls))
        self.barrier.wait()
        spans = [c.recv() for c in self.conns][:threads]
        return max(t1 for _, t1 in spans) - min(t0 for t0, _ in spans)

    def answer(self, name: str, query: str, threads: int, n: int) -> np.ndarray:
        for c in self.conns[:threads]:
            c.send(("answer", (name, threads), query))
        parts = [c.recv() for c in self.conns[:threads]]
        out = np.empty(n, parts[0].dtype)
        for k, part in enumerate(parts):
            out[share_index(n, k, threads)] = part
        return out

    def cpu_seconds(self) -> float:
        return sum(self._all([("cpu",)] * self.parts))

    def close(self) -> None:
        for c in self.conns:
            c.send(("stop",))
        for p in self.procs:
            p.join(10)


# ---------------------------------------------------------------- the machine and its load


def machine() -> dict:
    info = {"cpu": platform.processor() or "unknown", "cores": os.cpu_count()}
    try:
        fields = {}
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            k, _, v = line.partition(":")
            fields.setdefault(k.strip(), v.strip())
        info["cpu"] = (f"{fields.get('model name', 'unknown')} (family "
                       f"{fields.get('cpu family', '?')}, model {fields.get('model', '?')})")
    except OSError:
        pass
    info["simd"] = vc.testing.simd_level()
    info["embreex"] = _version("embreex")
    info["viscache_rs"] = _version("viscache_rs")
    return info


def _version(package: str) -> str:
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version(package)
    except PackageNotFoundError:
        return "unknown"


def busy_seconds() -> float | None:
    """CPU seconds every program on the machine has spent busy since boot (/proc/stat)."""
    try:
        cols = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
    except OSError:
        return None
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(c) for c in cols[:8])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


class OtherLoad:
    """Cores kept busy by programs other than this script and its workers, on average
    since ``start``."""

    def __init__(self, pool: EmbreePool):
        self.pool = pool
        self.start()

    def _ours(self) -> float:
        t = os.times()
        return t.user + t.system + self.pool.cpu_seconds()

    def start(self) -> None:
        self.t, self.busy, self.ours = time.perf_counter(), busy_seconds(), self._ours()

    def cores(self) -> float:
        busy = busy_seconds()
        if busy is None or self.busy is None:
            return float("nan")
        other = (busy - self.busy) - (self._ours() - self.ours)
        return max(0.0, other / (time.perf_counter() - self.t))


# ---------------------------------------------------------------- workloads and one scene


def camera_rays(setup, passes: int = 16, by_pixel: bool = False
                ) -> tuple[np.ndarray, np.ndarray]:
    """``passes`` jittered rays per pixel at 160x120, pass after pass or (``by_pixel``)
    pixel after pixel."""
    cam = setup.camera.with_resolution(160, 120)
    rays = [cam.rays(seed=k, jitter=True) for k in range(passes)]
    origins, dirs = (np.stack([r[i] for r in rays]) for i in (0, 1))  # (pass, pixel, 3)
    if by_pixel:
        origins, dirs = origins.swapaxes(0, 1), dirs.swapaxes(0, 1)
    return (np.ascontiguousarray(origins.reshape(-1, 3), np.float32),
            np.ascontiguousarray(dirs.reshape(-1, 3), np.float32))


def same_hits(ours: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    both_miss = ~np.isfinite(ours) & ~np.isfinite(theirs)
    with np.errstate(invalid="ignore"):
        close = np.abs(ours - theirs) <= 1e-3 * np.abs(theirs)
    return both_miss | close


def workloads(setup, quick: bool) -> dict:
    scene = setup.scene

    def f32(rays):
        return tuple(np.ascontiguousarray(a, np.float32) for a in rays)

    if quick:
        return {
            "incoherent": f32(vc.testing.ground_hemisphere_rays(scene, 1 << 17, seed=1)),
            "bundles": f32(vc.testing.record_bundle_rays(scene, 128, 32, seed=1)),
            "shading": f32(vc.testing.view_shading_rays(setup, passes=4, seed=1)),
            "camera": camera_rays(setup, passes=2),
            "pixels": camera_rays(setup, passes=2, by_pixel=True),
        }
    return {
        "incoherent": f32(vc.testing.ground_hemisphere_rays(scene, 1 << 20, seed=1)),
        "bundles": f32(vc.testing.record_bundle_rays(scene, 1000, 32, seed=1)),
        "shading": f32(vc.testing.view_shading_rays(setup, seed=1)),
        "camera": camera_rays(setup),
        "pixels": camera_rays(setup, by_pixel=True),
    }


def time_workload(scene, pool: EmbreePool, name: str, origins: np.ndarray,
                  dirs: np.ndarray, repeats: int, min_seconds: float) -> dict:
    """One workload's row: speeds at 1 and 2 threads each, ratios and agreement."""
    n = len(origins)
    closest = name in ("camera", "pixels")
    query = "DISTANCE" if closest else "OCCLUDED"
    pool.set_rays(name, origins, dirs)

    def ours(threads: int) -> np.ndarray:
        if closest:
            return scene.intersect(origins, dirs, threads=threads)["t"].astype(np.float64)
        return scene.occluded(origins, dirs, threads=threads)

    def theirs(threads: int) -> np.ndarray:
        answer = pool.answer(name, query, threads, n)
        if closest:
            t = answer.astype(np.float64)
            return np.where(t < 1e30, t, np.inf)
        return answer >= 0

    def ours_timed(calls: int, threads: int) -> float:
        t = time.perf_counter()
        for _ in range(calls):
            ours(threads)
        return time.perf_counter() - t

    fns = {}
    for th in (1, 2):
        fns[f"ours{th}"] = lambda calls, th=th: ours_timed(calls, th)
        fns[f"embree{th}"] = lambda calls, th=th: pool.time(name, query, th, calls)
    times = interleaved_times(fns, repeats, min_seconds)
    answers = {th: ours(th) for th in (1, 2)}
    agree = same_hits if closest else np.equal
    hit = np.isfinite(answers[1]) if closest else answers[1]
    row = {"rays": n, "occluded_fraction": float(np.mean(hit)),
           "ours_threads_agree": bool(np.array_equal(answers[1], answers[2]))}
    for th in (1, 2):
        t_ours, t_embree = min(times[f"ours{th}"]), min(times[f"embree{th}"])
        ratios = np.array(times[f"embree{th}"]) / np.array(times[f"ours{th}"])
        row[f"ours{th}_s"] = t_ours
        row[f"embree{th}_s"] = t_embree
        row[f"ours{th}_rays_per_s"] = n / t_ours
        row[f"embree{th}_rays_per_s"] = n / t_embree
        row[f"ratio{th}"] = float(np.median(ratios))
        row[f"ratio{th}_range"] = [float(ratios.min()), float(ratios.max())]
        row[f"agreement{th}"] = float(agree(answers[th], theirs(th)).mean())
    return row


def run(scene_name: str, pool: EmbreePool, repeats: int, quick: bool,
        min_seconds: float) -> dict:
    load = OtherLoad(pool)
    setup = vc.scenes.load(scene_name)
    scene = setup.scene
    build_s = scene.build(threads=2)
    stats = scene.bvh_stats()
    builder = stats["quality"] + (" (objects apart)" if stats["objects_apart"] else "")
    embree_build_s = pool.load(np.ascontiguousarray(scene.triangles(), np.float32))
    result = {"scene": scene_name, "triangles": int(scene.num_triangles),
              "our_build_s": build_s, "embree_build_s": embree_build_s, "builder": builder,
              "workloads": {}}
    for name, (o, d) in workloads(setup, quick).items():
        result["workloads"][name] = time_workload(scene, pool, name, o, d, repeats,
                                                  min_seconds)
    result["other_load_cores"] = load.cores()
    return result


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--scenes", nargs="+", default=None)
    ap.add_argument("--repeats", type=int, default=None,
                    help="timings per function (default 5; 2 with --quick)")
    ap.add_argument("--quick", action="store_true",
                    help="cornell and garage unless --scenes, smaller workloads")
    ap.add_argument("--json", default="results/peer_embree.json")
    args = ap.parse_args()
    repeats = args.repeats if args.repeats is not None else (2 if args.quick else 5)
    if repeats < 1:
        ap.error("--repeats must be at least 1")
    names = args.scenes or (["cornell", "garage"] if args.quick else vc.scenes.suite_names())
    unknown = sorted(set(names) - set(vc.scenes.suite_names()) - set(vc.scenes.names()))
    if unknown:
        ap.error(f"--scenes: unknown {', '.join(unknown)}")
    info = machine()
    info["date"] = time.strftime("%Y-%m-%d %H:%M %Z")
    info["load_average_at_start"] = os.getloadavg()
    info["command"] = " ".join(["python", "benches/peer_embree.py", *sys.argv[1:]])
    pool = EmbreePool(2)
    results = []
    try:
        for k, name in enumerate(names):
            t = time.perf_counter()
            results.append(run(name, pool, repeats, args.quick, 0.02 if args.quick else 0.05))
            print(f"[{k + 1}/{len(names)}] {name}: {time.perf_counter() - t:.0f} s, other "
                  f"programs' load {results[-1]['other_load_cores']:.2f} cores",
                  file=sys.stderr, flush=True)
    finally:
        pool.close()
    report(info, results)
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"machine": info, "scenes": results}, indent=2))
    print(f"wrote {path}")


def report(info: dict, results: list) -> None:
    print(f"{info['date']}; {info['cpu']}, {info['cores']} cores; our kernels: "
          f"{info['simd']}; embreex {info['embreex']} (robust=False, one process per "
          f"thread); load average at start "
          f"{', '.join(f'{x:.2f}' for x in info['load_average_at_start'])}")
    print("x Embree: ratio of speeds at equal threads (> 1: we are faster), median over the "
          "repeats [least, greatest]")
    print(f"{'scene':<10}{'workload':<12}{'rays':>9}{'occl.':>7}{'ours Mr/s 1,2':>15}"
          f"{'Embree Mr/s 1,2':>17}{'x Embree 1 thread':>21}{'x Embree 2 threads':>21}"
          f"{'agreement':>11}{'load':>6}")

    def ratio(w, th):
        lo, hi = w[f"ratio{th}_range"]
        return f"{w[f'ratio{th}']:.2f} [{lo:.2f}, {hi:.2f}]"

    for r in results:
        for name, w in r["workloads"].items():
            agree = min(w["agreement1"], w["agreement2"])
            print(f"{r['scene']:<10}{name:<12}{w['rays']:>9}{w['occluded_fraction']:>7.3f}"
                  f"{w['ours1_rays_per_s'] / 1e6:>7.2f},{w['ours2_rays_per_s'] / 1e6:>7.2f}"
                  f"{w['embree1_rays_per_s'] / 1e6:>9.2f},{w['embree2_rays_per_s'] / 1e6:>7.2f}"
                  f"{ratio(w, 1):>21}{ratio(w, 2):>21}{agree:>11.6f}"
                  f"{r['other_load_cores']:>6.2f}")
    print(f"\n{'workload':<12}{'geomean 1 thread':>18}{'worst 1 thread':>24}"
          f"{'geomean 2 threads':>19}{'worst 2 threads':>24}{'least agreement':>17}")
    for name in results[0]["workloads"]:
        cells = []
        for th in (1, 2):
            ratios = {r["scene"]: r["workloads"][name][f"ratio{th}"] for r in results}
            s = vc.metrics.worst_and_mean(ratios, higher_is_worse=False)
            cells.append(f"{s['geomean']:>18.2f}{s['worst']:>17} ({s['worst_value']:.2f})")
        agree = min(min(r["workloads"][name]["agreement1"], r["workloads"][name]["agreement2"])
                    for r in results)
        print(f"{name:<12}{cells[0]}{cells[1]}{agree:>17.6f}")
    for side, label in (("ours", "ours"), ("embree", "Embree")):
        gains = [w[f"{side}2_rays_per_s"] / w[f"{side}1_rays_per_s"]
                 for r in results for w in r["workloads"].values()]
        print(f"{label} at 2 threads over 1 (best timings): geometric mean "
              f"{np.exp(np.mean(np.log(gains))):.2f}, range {min(gains):.2f}-{max(gains):.2f}")
    split = [r["scene"] for r in results
             if not all(w["ours_threads_agree"] for w in r["workloads"].values())]
    print("ours at 1 and 2 threads: " + ("identical answers" if not split
                                         else f"answers differ on {', '.join(split)}"))
    print("builds (ours 2 threads, Embree both processes): " + ", ".join(
        f"{r['scene']} {r['builder']} {r['our_build_s']:.2f} s / {r['embree_build_s']:.2f} s"
        for r in results))
    loads = [r["other_load_cores"] for r in results]
    print(f"other programs' load while scenes ran: {min(loads):.2f}-{max(loads):.2f} cores "
          f"(of {info['cores']})")


if __name__ == "__main__":
    main()
