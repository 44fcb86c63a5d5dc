"""viscache_rs: Monte Carlo direct illumination that exploits visibility correlation.

The Rust core (``viscache_rs._core``) traces rays, builds G-buffers and, in later modules,
caches visibility; this package re-exports it and adds built-in scenes, I/O and the
``viscache`` command line.
"""

from . import octahedral, scenes, testing
from ._core import Camera, Material, Scene, Setup, __version__

__all__ = ["Camera", "Material", "Scene", "Setup", "__version__", "octahedral", "scenes", "testing"]
