"""Type checks of the objects the Python front ends take (a setup, scene, camera, map or
cache), so that a wrong one raises TypeError naming the argument before any work, rather
than an AttributeError from deep inside the call."""

from __future__ import annotations

from typing import Any

from ._core import Camera, EnvMap, GBuffer, Scene, VisibilityCache

_SETUP = "a Setup (vc.scenes.load(name) or vc.Setup(scene, camera, envmap))"


def check_setup(setup: Any, camera: bool = True, envmap: bool = True,
                name: str = "setup") -> None:
    """Raises TypeError naming ``name`` unless ``setup.scene`` is a Scene and, where the
    call reads them (``camera``, ``envmap``), ``setup.camera`` a Camera and
    ``setup.envmap`` an EnvMap."""
    wanted: list[tuple[str, type]] = [("scene", Scene)]
    wanted += [("camera", Camera)] if camera else []
    wanted += [("envmap", EnvMap)] if envmap else []
    for attr, cls in wanted:
        if not isinstance(getattr(setup, attr, None), cls):
            why = f" (its .{attr} is not a {cls.__name__})" if hasattr(setup, attr) else ""
            raise TypeError(f"{name}: expected {_SETUP}, got {type(setup).__name__}{why}")


def check_optional(value: Any, name: str, cls: type, what: str) -> None:
    """Raises TypeError naming ``name`` unless ``value`` is None or a ``cls``."""
    if value is not None and not isinstance(value, cls):
        raise TypeError(f"{name}: expected {what} or None, got {type(value).__name__}")


def check_call(setup: Any, camera: Any = None, envmap: Any = None, cache: Any = None,
               gbuffer: Any = None, lit: bool = True) -> None:
    """The checks of a call that renders ``setup`` through ``camera`` (default: the
    setup's, or the G-buffer's) under ``envmap`` (default: the setup's; ``lit=False``: a
    call that reads no map, such as ambient occlusion)."""
    check_optional(camera, "camera", Camera, "a Camera (vc.Camera.look_at)")
    check_optional(envmap, "envmap", EnvMap, "an EnvMap")
    check_optional(cache, "cache", VisibilityCache, "a VisibilityCache")
    check_optional(gbuffer, "gbuffer", GBuffer, "a GBuffer (from Scene.gbuffer)")
    check_setup(setup, camera=camera is None and gbuffer is None,
                envmap=lit and envmap is None)
