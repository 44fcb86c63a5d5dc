"""The baseline renderer: direct illumination from the environment map and area lights.

``render(setup, camera=None, spp=None, method="mis", seed=0, threads=None, progress=True,
time_budget=None, envmap=None, product_level=5)`` renders ``setup.scene`` lit by
``setup.envmap`` (or ``envmap``) and the scene's area lights, through ``camera`` (default: the
setup's). Methods:

- ``"env"``: light sampling (the map's own distribution, one point per area light);
- ``"bsdf"``: BSDF sampling (what the sampled ray finds);
- ``"mis"``: both, with the power heuristic;
- ``"product"``: product importance sampling of map x BSDF (CAM08 sec. 5.5); area lights
  by light sampling.

All four are unbiased estimators of the same image. ``spp`` defaults to 16; with a
``time_budget`` (seconds) the render runs passes of one sample per pixel until the budget
is spent (at most ``spp`` passes if given) and ``stats["spp"]`` says how many it made.
The result is bit-identical for any ``threads`` at a fixed seed and sample count.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from . import _core

_UNBOUNDED_SPP = 1 << 20


@dataclass
class RenderResult:
    """``image`` and ``variance`` (per-pixel variance of the mean) are (H, W, 3) float32;
    ``stats`` holds seconds, spp, samples, rays and per-stage CPU seconds."""

    image: np.ndarray
    variance: np.ndarray
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def standard_error(self) -> np.ndarray:
        """Per-pixel standard error of the mean, (H, W, 3)."""
        return np.sqrt(self.variance)


def render(
    setup,
    camera=None,
    spp: int | None = None,
    method: str = "mis",
    seed: int = 0,
    threads: int | None = None,
    progress: bool = True,
    time_budget: float | None = None,
    envmap=None,
    product_level: int = 5,
) -> RenderResult:
    """Renders direct illumination of a built-in or user setup; see the module docstring."""
    camera = setup.camera if camera is None else camera
    envmap = setup.envmap if envmap is None else envmap
    if spp is None:
        spp = _UNBOUNDED_SPP if time_budget is not None else 16
    bar = _progress_bar(progress, spp, time_budget, method)
    try:
        callback = None
        if bar is not None:

            def callback(done: int, planned: int) -> bool:
                bar.update(done - bar.n)
                return True

        out = _core.render(
            setup.scene,
            envmap,
            camera,
            spp,
            method,
            seed=seed,
            threads=threads,
            time_budget=time_budget,
            product_level=product_level,
            callback=callback,
        )
    finally:
        if bar is not None:
            bar.close()
    return RenderResult(out["image"], out["variance"], out["stats"])


def _progress_bar(progress: bool, spp: int, time_budget: float | None, method: str):
    if not progress:
        return None
    total = None if time_budget is not None and spp >= _UNBOUNDED_SPP else spp
    return tqdm(total=total, desc=f"render ({method})", unit="spp", leave=False)


__all__ = ["RenderResult", "render"]
