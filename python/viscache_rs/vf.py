"""``vc.vf``: visibility filtering's view-independent half (Chen et al. 2014, eq. 1-3).

``ProxyGrid(setup, proxies=24000, voxels=(6, 6, 6), seed=0, threads=None, envmap=None,
table_slots=None)`` places about ``proxies`` point proxies on ``setup.scene`` by area,
lights them by shadow rays from ``envmap`` (default: the setup's) and the scene's area
lights (each a first-bounce surface VPL), and sorts them into a ``voxels`` grid with each
voxel's bands 0-1 SH. Build it once and render any number of views from it::

    grid = vc.vf.ProxyGrid(setup, proxies=24_000, voxels=6, seed=0)
    for cam in cameras:
        res = vc.render(setup, camera=cam, method="vf", proxies=grid, direct=False)

``proxies=`` takes either an integer (the render builds its own grid, from ``voxels`` and
its ``seed``) or a ``ProxyGrid``; a grid built with the render's ``seed`` gives the same
image, bit for bit, as the render building its own. A grid is refused (ValueError naming
``proxies``) by a render of another scene's geometry or under another ``envmap`` object
(its VPLs carry the lighting of its build), and with ``voxels=`` (the grid fixes it).
A render from a grid leaves the build out of ``stats["seconds"]``;
``stats["voxelisation_seconds"]`` is the build's and ``stats["grid_given"]`` is True.
``grid.stats`` holds the build's figures (proxies, vpls, occupied and non-empty voxels,
seconds, the VPLs' total flux).
"""

from __future__ import annotations

from typing import Any

from . import _core
from ._checks import check_optional, check_setup


class ProxyGrid(_core.ProxyGrid):
    """Point proxies, their VPLs and voxel grids of a setup, reusable across views:
    ``ProxyGrid(setup, proxies=24000, voxels=(6, 6, 6), seed=0, threads=None,
    envmap=None, table_slots=None)``; see :mod:`viscache_rs.vf`."""

    __slots__ = ()

    def __new__(
        cls,
        setup: Any,
        proxies: int | None = None,
        voxels: int | tuple[int, int, int] | None = None,
        seed: int = 0,
        threads: int | None = None,
        envmap: _core.EnvMap | None = None,
        table_slots: int | None = None,
    ) -> ProxyGrid:
        check_optional(envmap, "envmap", _core.EnvMap, "an EnvMap")
        check_setup(setup, camera=False, envmap=envmap is None)
        env = setup.envmap if envmap is None else envmap
        return super().__new__(cls, setup.scene, env, proxies, voxels, seed, threads,
                               table_slots)


__all__ = ["ProxyGrid"]
