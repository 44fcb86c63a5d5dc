"""viscache_rs: Monte Carlo direct illumination that exploits visibility correlation.

The Rust core (``viscache_rs._core``) traces rays, builds G-buffers and, in later modules,
caches visibility; this package re-exports it and adds built-in scenes, I/O and the
``viscache`` command line.
"""

from . import envmaps, scenes, testing
from ._core import Camera, EnvMap, Material, Scene, Setup, __version__

__all__ = [
    "Camera",
    "EnvMap",
    "Material",
    "Scene",
    "Setup",
    "__version__",
    "envmaps",
    "scenes",
    "testing",
]
