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

Animated variants (``animated_names()``; ``load("dynamics", animated=True)``): the
``dynamics`` sphere rolls 2 m toward the open ground and back every 60 frames.
``setup.at_frame(i)`` moves it (frame 0 is the static scene), ``setup.moving_object`` is its
object id and ``setup.moving_bounds()`` its bounds at the current frame.
"""

import numpy as np

from ._core import Scene, Setup, animated_scene_names, load_scene, scene_names

__all__ = ["Setup", "animated_names", "load", "names", "without"]


def names() -> list[str]:
    """Names of the built-in scenes."""
    return list(scene_names())


def animated_names() -> list[str]:
    """Names of the built-in scenes that have an animated variant."""
    return list(animated_scene_names())


def load(name: str, detail: float = 1.0, seed: int = 0, animated: bool = False) -> Setup:
    """Builds the built-in scene ``name``.

    Returns a :class:`Setup` with ``.scene``, ``.camera`` (256x192 by default; use
    ``setup.camera.with_resolution(w, h)`` for other sizes) and ``.envmap``, the scene's
    default :class:`EnvMap` (sky and sun for garden, dynamics and hairball; bright windows
    mostly hidden by the roof for garage; constant white for the closed cornell box). The
    same ``seed`` always gives the same triangles.

    ``animated=True`` gives the animated variant (only for :func:`animated_names`; other
    names raise ValueError naming ``animated``): at frame 0 it is the same scene; move it
    with ``setup.at_frame(i)``.
    """
    return load_scene(name, detail=detail, seed=seed, animated=animated)


def without(setup: Setup, drop, name: str | None = None) -> Setup:
    """A copy of ``setup`` whose scene lacks the objects named in ``drop`` (materials and the
    other objects' names kept; same camera and environment map). For example the Cornell
    box without ``("ceiling", "light")`` sees the sky, and the garage without ``("roof",)``
    gives a deliberately wrong visibility cache. Area lights are not carried over."""
    drop = set(drop)
    names = setup.scene.object_names()
    unknown = drop - set(names)
    if unknown:
        raise ValueError(f"drop: no objects named {sorted(unknown)}; the scene has {names}")
    tris = setup.scene.triangles()
    ids = setup.scene.object_ids()
    scene = Scene()
    for k, obj in enumerate(names):
        if obj in drop:
            continue
        t = tris[ids == k]
        faces = np.arange(3 * len(t)).reshape(-1, 3)
        scene.add_mesh(t.reshape(-1, 3), faces, material=setup.scene.material(k), name=obj)
    return Setup(scene, setup.camera, setup.envmap, name=name or f"{setup.name}-without")
