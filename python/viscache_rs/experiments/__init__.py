"""Experiments that measure the speed/accuracy trade of visibility caching (CAM08 sec. 4-7).

Each experiment is a module here with a ``DESCRIPTION`` string and a ``run(ctx)`` function
that takes an :class:`ExperimentContext`. ``viscache experiment NAME [--quick]`` (or
:func:`run`) creates ``results/NAME/`` and the experiment writes into it:

- ``results.json``: every figure it measured (:meth:`ExperimentContext.record`);
- ``results.md``: its tables in markdown (:meth:`ExperimentContext.table`), also printed;
- images as float EXR plus tone-mapped PNG (:meth:`ExperimentContext.image`);
- matplotlib figures as PNG (:meth:`ExperimentContext.figure`).

``--quick`` runs in minutes on 2 cores (small images, few sample counts); the full mode
follows the paper's settings more closely and can take much longer.

:func:`sweep` runs a list of (scene, method, parameters, spp or time budget, seed) points
as Dask tasks, each measured against its scene's reference, into one pandas table
(:mod:`~viscache_rs.experiments.sweeps`); ``tradeoff`` and ``variance-table`` run their
points through it, in this process by default or on a cluster (``client=``).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

from ._context import ExperimentContext
from .sweeps import sweep

#: Experiment name -> module name.
_MODULES = {
    "variance-table": "variance_table",
    "correlation": "correlation",
    "ao": "ambient_occlusion",
    "animation": "animation",
    "tradeoff": "tradeoff",
    "relight": "relight",
    "irradiance-cache": "irradiance_cache",
    "importance-cache": "importance_cache",
    "vf": "vf",
    "proxies": "proxies",
}


def names() -> list[str]:
    """Names of the experiments that are available."""
    return [n for n in _MODULES if _module(n) is not None]


def _module(name: str):
    try:
        return importlib.import_module(f"{__name__}.{_MODULES[name]}")
    except ModuleNotFoundError as e:
        if e.name == f"{__name__}.{_MODULES[name]}":
            return None
        raise


def describe(name: str) -> str:
    """One-paragraph description of experiment ``name``."""
    return _get(name).DESCRIPTION


def _get(name: str):
    mod = _module(name) if name in _MODULES else None
    if mod is None:
        raise ValueError(f"name: unknown experiment {name!r}; expected one of {names()}")
    return mod


def run(
    name: str,
    quick: bool = False,
    out: str | Path = "results",
    seed: int = 0,
    threads: int | None = None,
    progress: bool | None = None,
    client: Any = "serial",
) -> ExperimentContext:
    """Runs experiment ``name`` and writes ``out/name/``; returns the context, whose
    ``results`` dict holds every recorded figure. ``client``: where the sweeps of
    ``tradeoff`` and ``variance-table`` run (:func:`sweep`'s ``client``): ``"serial"``
    (default) in this process with ``threads`` per render, None a new LocalCluster, a
    scheduler's address or a ``distributed.Client``; the other experiments ignore it."""
    mod = _get(name)
    ctx = ExperimentContext(
        name=name,
        out=Path(out) / name,
        quick=quick,
        seed=seed,
        threads=threads,
        progress=progress,
        client=client,
    )
    try:
        mod.run(ctx)
    finally:
        ctx.close()
    ctx.finish()
    return ctx


__all__ = ["ExperimentContext", "describe", "names", "run", "sweep"]
