"""The output side of an experiment: figures to JSON, tables to markdown, images, plots."""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..io import atomic_path, to_srgb8, write_bytes, write_exr, write_png


def _jsonable(value: Any) -> Any:
    """Numbers, arrays and nested containers as plain JSON values (NaN/inf as strings)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


@dataclass
class ExperimentContext:
    """Where an experiment writes, and how hard it should work.

    ``quick`` asks for a run of minutes on 2 cores; ``seed`` drives every random choice;
    ``threads`` is passed to the core (None: all cores); ``progress``: bars (True),
    none (False), or only when stderr is a terminal (None).
    ``client`` is where sweeps run (``vc.experiments.sweep``'s ``client``).
    """

    name: str
    out: Path
    quick: bool = False
    seed: int = 0
    threads: int | None = None
    progress: bool | None = None
    client: Any = "serial"
    results: dict[str, Any] = field(default_factory=dict)
    _tables: list[str] = field(default_factory=list)
    _owned: list[Any] = field(default_factory=list)
    _start: float = field(default_factory=time.perf_counter)

    def sweep(self, points: list[dict[str, Any]]):
        """``points`` run by ``vc.experiments.sweep`` on this context's client: in this
        process with ``threads`` per render, or one thread per render on a cluster."""
        from .sweeps import SERIAL, sweep

        if self.client == SERIAL:
            return sweep(points, SERIAL, threads=self.threads or os.cpu_count() or 1,
                         progress=self.progress)
        if self.client is None or isinstance(self.client, str):
            # One cluster (or connection) for all of the experiment's sweeps, closed by
            # close(): a LocalCluster takes seconds to start.
            from .sweeps import _client

            client, cluster, close = _client(self.client, None)
            self._owned = [client, cluster, close]
            self.client = client
        return sweep(points, self.client, progress=self.progress)

    def close(self) -> None:
        """Closes the client and cluster that :meth:`sweep` started, if any."""
        client, cluster, close = self._owned or (None, None, False)
        self._owned = []
        if close and client is not None:
            client.close()
        if cluster is not None:
            cluster.close()

    def __post_init__(self) -> None:
        self.out = Path(self.out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.results.update(
            {"experiment": self.name, "quick": self.quick, "seed": self.seed,
             "threads": self.threads}
        )

    def record(self, key: str, value: Any) -> Any:
        """Stores ``value`` (numbers, arrays, dicts, lists) under ``key`` in results.json."""
        self.results[key] = _jsonable(value)
        return value

    def table(self, title: str, header: list[str], rows: list[list[Any]]) -> str:
        """Adds a markdown table to results.md, prints it and returns its text."""
        def cell(v: Any) -> str:
            if isinstance(v, float | np.floating):
                return f"{v:.4g}"
            return str(v)

        lines = [f"## {title}", "", "| " + " | ".join(header) + " |",
                 "|" + "|".join("---" for _ in header) + "|"]
        lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
        text = "\n".join(lines) + "\n"
        self._tables.append(text)
        print(text)
        return text

    def note(self, text: str) -> None:
        """Adds a paragraph to results.md (and prints it)."""
        self._tables.append(text.rstrip() + "\n")
        print(text)

    def image(self, name: str, rgb: np.ndarray, exposure: float = 1.0) -> Path:
        """Writes ``name.exr`` (float RGB) and ``name.png`` (sRGB after ``exposure``)."""
        rgb = np.asarray(rgb, dtype=np.float32)
        if rgb.ndim == 2:
            rgb = np.repeat(rgb[..., None], 3, axis=2)
        write_exr(self.out / f"{name}.exr", rgb)
        return write_png(self.out / f"{name}.png", to_srgb8(rgb, exposure))

    def figure(self, name: str, fig) -> Path:
        """Saves a matplotlib figure as ``name.png`` and closes it."""
        import matplotlib.pyplot as plt

        path = self.out / f"{name}.png"
        with atomic_path(path) as temp:
            fig.savefig(temp, dpi=120, bbox_inches="tight", format="png")
        plt.close(fig)
        return path

    def finish(self) -> None:
        """Writes results.json and results.md."""
        self.results["seconds"] = time.perf_counter() - self._start
        write_bytes(self.out / "results.json", (json.dumps(self.results, indent=2) + "\n").encode())
        head = f"# {self.name}{' (quick)' if self.quick else ''}\n\n"
        write_bytes(self.out / "results.md", (head + "\n".join(self._tables)).encode())


def pyplot():
    """matplotlib's pyplot on the Agg backend (no display needed)."""
    try:
        import matplotlib
    except ImportError as e:
        raise ImportError("the experiments plot with matplotlib: install the extra with "
                          "pip install 'viscache_rs[experiments]'") from e

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
