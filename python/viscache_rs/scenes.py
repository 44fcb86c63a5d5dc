"""Built-in procedural scenes, generated in Rust from a seed.

=========  =================================================================================
name       purpose
=========  =================================================================================
cornell    closed Cornell box with two blocks (~1k triangles): known-answer tests.
garage     building with a deep overhang, openings, ground and car-sized boxes; the camera
           looks into the shadowed part, where most of the bright sky is occluded.
garden     ground covered by thin grass blades (~400k triangles) and a few tulips:
           near-random visibility, the hard case for visibility reuse.
dynamics   a few objects on a large plane: little occlusion.
hairball   a dense tangle of thin tubes (~1.5M triangles) over a plane: complex geometry.
=========  =================================================================================

Triangle counts are at ``detail=1``; ``detail`` in (0, 16] scales them roughly linearly.
"""

from ._core import Setup, load_scene, scene_names

__all__ = ["Setup", "load", "names"]


def names() -> list[str]:
    """Names of the built-in scenes."""
    return list(scene_names())


def load(name: str, detail: float = 1.0, seed: int = 0) -> Setup:
    """Builds the built-in scene ``name``.

    Returns a :class:`Setup` with ``.scene``, ``.camera`` (256x192 by default; use
    ``setup.camera.with_resolution(w, h)`` for other sizes) and ``.envmap``, the scene's
    default :class:`EnvMap` (sky and sun for garden, dynamics and hairball; bright windows
    mostly hidden by the roof for garage; constant white for the closed cornell box). The
    same ``seed`` always gives the same triangles.
    """
    return load_scene(name, detail=detail, seed=seed)
