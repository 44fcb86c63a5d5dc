"""Sweeps: many (scene, method, parameters, spp or time budget, seed) points, one Dask task
each, measured against their scenes' references, as one table.

``sweep(points, client=None)`` checks every point (``_sweep_points``), submits one task per
distinct reference (scene, size and reference settings) and per distinct visibility cache,
then one task per point that takes them as futures: the scheduler ships each reference to
the workers that need it, and a lost one is made again from its seeds. A point's task
renders with ``threads=1`` (its worker's one core; the render releases the GIL throughout)
and returns its row. The rows come back as a pandas DataFrame in the points' order,
whatever order they finished in, so a sweep is a function of its points: run again, on
another cluster, or with workers lost on the way, it gives the same rows but for the
columns of :data:`TIMING_COLUMNS`.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._progress import progress_bar, wants_bar
from ..io import atomic_path
from . import _sweep_tasks as tasks
from ._sweep_points import POINT_KEYS, check_points, load
from ._sweep_tasks import TIMING_COLUMNS

if TYPE_CHECKING:
    import pandas as pd

#: ``client`` value that runs the points one after another in this process (no Dask):
#: the baseline of ``benches/sweep_dask.py`` and the experiments' default.
SERIAL = "serial"

#: What a sweep writes into its output folder.
TABLE_FILE, PLOT_FILE = "sweep.parquet", "efficiency.png"


def _reference_args(p: dict[str, Any]) -> dict[str, Any] | None:
    """The arguments of the point's reference task (None: no reference)."""
    r = p["reference"]
    if r is None:
        return None
    return {"scene": p["scene"], "detail": p["detail"], "scene_seed": p["scene_seed"],
            "width": p["width"], "height": p["height"], "method": r["method"],
            "spp": r["spp"], "seed": r["seed"]}


def _cache_args(p: dict[str, Any]) -> dict[str, Any] | None:
    """The arguments of the point's cache task (None: no cache)."""
    if p["cache"] is None:
        return None
    return {"scene": p["scene"], "detail": p["detail"], "scene_seed": p["scene_seed"],
            "width": p["width"], "height": p["height"], "settings": p["cache"]}


def _cost(p: dict[str, Any]) -> tuple[float, float]:
    """A point's expected work, to order the tasks: its time budget (seconds, first), else
    its samples (pixels x spp x repeats)."""
    samples = p["width"] * p["height"] * (p["spp"] or 0) * p["repeats"]
    return (p["time_budget"] or 0.0) * p["repeats"], float(samples)


def _key(args: dict[str, Any] | None) -> str | None:
    """Points with equal arguments share one task."""
    return None if args is None else json.dumps(args, sort_keys=True)


def _table(rows: list[dict[str, Any]]) -> pd.DataFrame:
    import pandas as pd

    return pd.DataFrame(sorted(rows, key=lambda r: r["index"])).reset_index(drop=True)


def _serial(points, threads: int, on_row, progress: bool | None) -> list[dict[str, Any]]:
    with progress_bar(progress, "sweep", "points", total=len(points)) as bar:
        return _serial_rows(points, threads, on_row, bar)


def _serial_rows(points, threads: int, on_row, bar) -> list[dict[str, Any]]:
    refs: dict[str | None, Any] = {None: None}
    caches: dict[str | None, Any] = {None: None}
    rows = []
    for i, p in enumerate(points):
        ra, ca = _reference_args(p), _cache_args(p)
        rk, ck = _key(ra), _key(ca)
        if ra is not None and rk not in refs:
            refs[rk] = tasks.reference(**ra, threads=threads)
        if ca is not None and ck not in caches:
            caches[ck] = tasks.cache(**ca, threads=threads)
        row = tasks.point(p, i, refs[rk], caches[ck], threads)
        rows.append(row)
        if on_row is not None:
            on_row(row)
        if bar is not None:
            bar(i + 1, len(points))
    return rows


def _client(client: Any, workers: int | None):
    """(client, cluster we started or None, whether we close the client)."""
    from distributed import Client, LocalCluster

    if client is None:
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                               processes=True, dashboard_address=None)
        return Client(cluster), cluster, True
    if isinstance(client, str):
        return Client(client), None, True
    return client, None, False


def _on_cluster(client, points, threads: int, on_row,
                progress: bool | None) -> list[dict[str, Any]]:
    from distributed import wait

    refs: dict[str | None, Any] = {None: None}
    caches: dict[str | None, Any] = {None: None}
    futures = {}
    for p in points:
        ra, ca = _reference_args(p), _cache_args(p)
        rk, ck = _key(ra), _key(ca)
        if ra is not None and rk not in refs:
            refs[rk] = client.submit(tasks.reference, **ra, threads=threads)
        if ca is not None and ck not in caches:
            caches[ck] = client.submit(tasks.cache, **ca, threads=threads)
    # The scheduler starts tasks in the order they were submitted: the longest first, so
    # that the sweep does not end on one long point while the other workers wait.
    for i in sorted(range(len(points)), key=lambda i: _cost(points[i]), reverse=True):
        p = points[i]
        rk, ck = _key(_reference_args(p)), _key(_cache_args(p))
        futures[client.submit(tasks.point, p, i, refs[rk], caches[ck], threads)] = i
    everything = [f for f in (*futures, *refs.values(), *caches.values()) if f is not None]
    try:
        if wants_bar(progress):
            from distributed import progress as bar

            bar(list(futures), notebook=False)
        rows = []
        pending = set(futures)
        while pending:
            # Short waits, so that Ctrl-C reaches this thread between them.
            try:
                done, not_done = wait(list(pending), timeout=0.2, return_when="FIRST_COMPLETED")
            except TimeoutError:
                continue
            for f in done:
                row = f.result()  # a task's exception is raised here, naming the point
                rows.append(row)
                if on_row is not None:
                    on_row(row)
            pending = set(not_done)
        return rows
    except BaseException:
        # Ctrl-C or a failed point: stop the rest of the sweep on the cluster.
        client.cancel(everything, force=True)
        raise


def sweep(
    points: Iterable[dict[str, Any]],
    client: Any = None,
    *,
    threads: int = 1,
    workers: int | None = None,
    progress: bool | None = False,
    on_row: Callable[[dict[str, Any]], Any] | None = None,
) -> pd.DataFrame:
    """Runs ``points`` (dicts with the keys of ``POINT_KEYS``; README "Sweeps") and returns
    their rows as a pandas DataFrame, one row per point in the points' order.

    ``client``: None starts a ``distributed.LocalCluster`` (``workers`` worker processes,
    default one per core, one thread each) and closes it afterwards; a
    ``distributed.Client`` is used as it is; a string is a scheduler's address
    (``"tcp://host:port"``) to connect to; ``"serial"`` runs the points one after
    another in this process, without Dask. ``threads``: the threads of each render (1:
    a worker's core). ``progress``: Dask's progress bar (in this process: a bar of
    points); None: only when stderr is a terminal. ``on_row(row)`` is called with
    each row as it arrives.

    Every point is checked before any work (ValueError/TypeError naming the point and the
    key). A point's row holds its settings, ``spp`` (the least per pixel), seconds
    (``render_seconds``; ``cache_seconds`` of a shared cache's build;
    ``total_seconds``), ``relmse`` on RGB against the reference (its variance share
    subtracted; ``relmse_raw`` without; ``relmse_r/g/b``), ``variance`` (the image's own
    relMSE estimate), ``var_r/g/b`` (mean per-pixel variance of the mean), ``efficiency``
    and ``efficiency_total`` (1 / (relMSE s), without and with the cache build), the
    cache's ``records``, and ``stats`` (the render's scalar figures as JSON). Ctrl-C stops
    the sweep and its tasks and raises KeyboardInterrupt."""
    checked = check_points(points)
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"threads: expected a positive integer, got {threads!r}")
    if client == SERIAL:
        return _table(_serial(checked, threads, on_row, progress))
    client, cluster, close = _client(client, workers)
    try:
        return _table(_on_cluster(client, checked, threads, on_row, progress))
    finally:
        if close:
            client.close()
        if cluster is not None:
            cluster.close()


def _at_least_a_decade(ax) -> None:
    """Log axes spanning at least two decades about their data: over less, matplotlib
    labels minor ticks and the labels overlap."""
    for get, set_ in ((ax.get_xlim, ax.set_xlim), (ax.get_ylim, ax.set_ylim)):
        lo, hi = get()
        if lo > 0 and hi / lo < 100:
            mid = math.sqrt(lo * hi)
            set_(mid / 10, mid * 10)


def plot(table: pd.DataFrame):
    """The efficiency plot: per scene, relMSE against seconds (render and cache build) and
    efficiency 1 / (relMSE s) against samples per pixel, one line per label."""
    from ._context import pyplot

    plt = pyplot()
    names = list(dict.fromkeys(table["scene"]))
    fig, axes = plt.subplots(len(names), 2, figsize=(11, 4.2 * len(names)), squeeze=False)
    for (a, b), name in zip(axes, names, strict=True):
        rows = table[table["scene"] == name]
        for label in dict.fromkeys(rows["label"]):
            rs = rows[(rows["label"] == label) & np.isfinite(rows["relmse"])
                      & (rows["relmse"] > 0)].sort_values("total_seconds")
            if len(rs) == 0:
                continue
            a.loglog(rs["total_seconds"], rs["relmse"], "o-", ms=4, label=label)
            rs = rs.sort_values("spp")
            b.loglog(rs["spp"], rs["efficiency_total"], "o-", ms=4, label=label)
        a.set(xlabel="seconds (render + cache build)", ylabel="relMSE (RGB)",
              title=f"{name}: relMSE against time")
        b.set(xlabel="samples per pixel", ylabel="efficiency 1/(relMSE s)",
              title=f"{name}: efficiency")
        for ax in (a, b):
            _at_least_a_decade(ax)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def write(table: pd.DataFrame, out: str | Path) -> list[Path]:
    """Writes ``out/sweep.parquet`` (the table less its images) and ``out/efficiency.png``;
    returns their paths. Everything is made before anything is written, and each file is
    written to a temporary beside it and renamed, so a failure or Ctrl-C leaves the folder
    as it was or holding whole files."""
    import io

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out: {out} is a file, not a folder")
    data = table.drop(columns=["image"], errors="ignore")
    parquet = io.BytesIO()
    data.to_parquet(parquet, engine="pyarrow", index=False)
    fig = plot(table)
    png = io.BytesIO()
    fig.savefig(png, dpi=110, bbox_inches="tight", format="png")
    import matplotlib.pyplot as plt

    plt.close(fig)
    written = []
    for name, payload in ((TABLE_FILE, parquet), (PLOT_FILE, png)):
        path = out / name
        with atomic_path(path) as temp:
            temp.write_bytes(payload.getvalue())
        written.append(path)
    return written


def summary(table: pd.DataFrame) -> str:
    """The table's main columns as text, for a terminal."""
    cols = ["label", "scene", "spp", "render_seconds", "cache_seconds", "relmse",
            "efficiency_total"]
    return table[cols].to_string(index=False, float_format=lambda v: f"{v:.4g}"
                                 if math.isfinite(v) else "-")


__all__ = ["PLOT_FILE", "POINT_KEYS", "SERIAL", "TABLE_FILE", "TIMING_COLUMNS", "load",
           "plot", "summary", "sweep", "write"]
