"""Scenes from mesh files: ``vc.Scene.load(path)`` (this module's :func:`load`).

The extension chooses the reader: ``.obj`` goes to :meth:`Scene.from_obj` (tobj; one object
per OBJ object or group), every other format trimesh reads (PLY, glTF/GLB, STL, OFF, ...)
to ``trimesh.load`` and :meth:`Scene.from_trimesh` (one object per scene-graph node, named
after it, with its node transform applied). Objects get the default Lambert material; set
others with ``scene.set_material``.
"""

from __future__ import annotations

import os

from ._core import Scene

__all__ = ["load"]


def load(path: str | os.PathLike[str]) -> Scene:
    """A :class:`Scene` read from the mesh file ``path``, by its extension (see the module
    docstring). A missing file raises FileNotFoundError; a format neither reader knows, a
    file its reader cannot parse, or one without a triangle raises ValueError; each names
    ``path``."""
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"path: expected a str or os.PathLike, got {type(path).__name__}")
    name = os.fspath(path)
    if not os.path.isfile(name):
        raise FileNotFoundError(f"{name}: no such mesh file")
    ext = os.path.splitext(name)[1].lower().lstrip(".")
    if ext == "obj":
        scene = Scene.from_obj(name)  # names the path in its own errors
    else:
        scene = _from_trimesh_file(name, ext)
    if scene.num_triangles == 0:
        raise ValueError(f"{name}: holds no triangles")
    return scene


def _from_trimesh_file(name: str, ext: str) -> Scene:
    import trimesh

    formats = sorted(trimesh.available_formats())
    if ext not in formats:
        what = f".{ext} files" if ext else "files without an extension"
        raise ValueError(f"{name}: no reader for {what} (OBJ, or what trimesh reads: "
                         f"{', '.join(formats)})")
    try:
        loaded = trimesh.load(name, file_type=ext, force="scene")
    except Exception as e:  # trimesh's readers raise what their parsers raise
        raise ValueError(f"{name}: cannot be read as {ext.upper()} ({e})") from e
    return Scene.from_trimesh(loaded)
