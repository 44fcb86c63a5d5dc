"""viscache_rs: Monte Carlo direct illumination that exploits visibility correlation.

The Rust core (``viscache_rs._core``) traces rays, samples lights and BSDFs, renders and
caches visibility (``VisibilityCache``); this package re-exports it, draws the progress bars
the core reports to, and adds built-in scenes, environment maps, I/O and the ``viscache``
command line.
"""

from . import (
    analysis,
    design,
    display,
    envmaps,
    experiments,
    metrics,
    mitsuba,
    models,
    octahedral,
    plot,
    scene_files,
    scenes,
    setup_files,
    testing,
    vf,
)
from ._core import (
    Camera,
    EnvMap,
    GBuffer,
    LightingPreview,
    Material,
    Proxies,
    Scene,
    Setup,
    VPLs,
    __version__,
)
from .ambient import AOResult, render_ao
from .cache import VisibilityCache
from .importance import ImportanceCache
from .irradiance import IrradianceCache
from .relight import Relighter, RelightResult
from .render import RenderResult, methods, preview, render

# Scene.load, Setup.load and Setup.save read and write files through Python libraries
# (trimesh, json), so they are attached here rather than written in Rust; _core.pyi
# declares them.
Scene.load = staticmethod(scene_files.load)  # type: ignore[method-assign]
Setup.load = staticmethod(setup_files.load)  # type: ignore[method-assign]
Setup.save = setup_files.save  # type: ignore[method-assign]
# The native G-buffer and map show themselves in Jupyter and save to EXR or PNG through
# numpy and the io helpers (``display``); _core.pyi declares them.
GBuffer._repr_png_ = display.gbuffer_repr_png  # type: ignore[method-assign]
GBuffer.save = display.gbuffer_save  # type: ignore[method-assign]
EnvMap._repr_png_ = display.envmap_repr_png  # type: ignore[method-assign]
EnvMap.save = display.envmap_save  # type: ignore[method-assign]

__all__ = [
    "AOResult",
    "Camera",
    "EnvMap",
    "GBuffer",
    "ImportanceCache",
    "IrradianceCache",
    "LightingPreview",
    "Material",
    "Proxies",
    "RelightResult",
    "Relighter",
    "RenderResult",
    "Scene",
    "Setup",
    "VPLs",
    "VisibilityCache",
    "__version__",
    "analysis",
    "design",
    "display",
    "envmaps",
    "experiments",
    "methods",
    "metrics",
    "mitsuba",
    "models",
    "octahedral",
    "plot",
    "preview",
    "render",
    "render_ao",
    "scene_files",
    "scenes",
    "setup_files",
    "testing",
    "vf",
]
