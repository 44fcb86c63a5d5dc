"""Setups as small JSON files, so that an experiment can be rerun from files:
``setup.save(path)`` and ``vc.Setup.load(path)`` (this module's :func:`save` and
:func:`load`).

The file names the meshes, materials, lights, environment map and camera; paths in it are
relative to the file's folder (absolute ones are kept as they are)::

    {
      "format": "viscache-setup", "version": 1, "name": "garage",
      "objects": [
        {"name": "floor", "mesh": "garage.parts/floor.ply",
         "material": {"kind": "lambert", "albedo": [0.8, 0.8, 0.8]}},
        {"name": "car", "mesh": "car.glb",
         "material": {"kind": "phong", "kd": [0.3, 0.1, 0.1], "ks": [0.5, 0.5, 0.5],
                      "exponent": 40.0}},
        {"name": "lamp", "mesh": "lamp.obj", "emission": [17.0, 12.0, 4.0]}
      ],
      "envmap": {"file": "garage.parts/envmap.exr"},
      "camera": {"eye": [0, 1.5, 6], "forward": [0, 0, -1], "up": [0, 1, 0],
                 "fov_deg": 45.0, "width": 256, "height": 192}
    }

- ``objects``: each ``mesh`` is read by :meth:`Scene.load` (any format it reads); each
  object of the file becomes one object of the setup, named ``name`` (``name/node`` when
  the file holds several), with ``material`` (default: :meth:`Scene.add_mesh`'s, Lambert
  0.7) and, if ``emission``
  (W/(m² sr), RGB) is given, emitting it as an area light (one-sided, on the winding
  normal's side).
- ``envmap``: ``{"file": EXR}`` (octahedral or lat-long, as :meth:`EnvMap.from_exr` reads
  it), ``{"constant": [r, g, b]}`` (each with an optional ``"resolution"``) or ``null``
  (black).
- ``camera``: a pinhole camera by :meth:`Camera.look_at` from ``eye`` toward ``forward``
  (or ``target``), ``fov_deg`` along the height.

:func:`save` writes the file and, beside it in ``<stem>.parts/``, one binary PLY per object
(its triangles exactly) and the map as an octahedral EXR (bit-exact; a black map as
``constant``), so ``load`` gives
back the same triangles, materials, lights, map and camera rays. It writes into a
temporary folder first and moves the results into place only once all are written.
Animated setups are saved at their current frame, without the animation; emission
textures are not kept.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from typing import Any

import numpy as np

from ._core import Camera, EnvMap, Material, Scene, Setup

__all__ = ["FORMAT", "VERSION", "load", "save"]

#: The ``format`` field of a setup file.
FORMAT = "viscache-setup"
#: The version :func:`save` writes and :func:`load` reads.
VERSION = 1

_TOP_KEYS = {"format", "version", "name", "objects", "envmap", "camera"}
_OBJECT_KEYS = {"name", "mesh", "material", "emission"}
_CAMERA_KEYS = {"eye", "forward", "target", "up", "fov_deg", "width", "height"}
_ENVMAP_KEYS = {"file", "resolution", "constant"}


def _material_dict(material: Material) -> dict[str, Any]:
    return {"kind": material.kind, **material.params()}


def _material(d: Any, where: str) -> Material:
    if not isinstance(d, dict) or d.get("kind") not in ("lambert", "phong"):
        raise ValueError(f"{where}: expected {{'kind': 'lambert' or 'phong', ...}}, got {d!r}")
    keys = {"kind", "albedo"} if d["kind"] == "lambert" else {"kind", "kd", "ks", "exponent"}
    if set(d) != keys:
        raise ValueError(f"{where}: a {d['kind']} material has the keys {sorted(keys)}, got "
                         f"{sorted(d)}")
    try:
        if d["kind"] == "lambert":
            return Material.lambert(d["albedo"])
        return Material.phong(d["kd"], d["ks"], d["exponent"])
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: {e}") from e


def _check_keys(d: Any, allowed: set[str], where: str) -> dict[str, Any]:
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected an object, got {type(d).__name__}")
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown key {unknown[0]!r} (known: {sorted(allowed)})")
    return d


def save(self: Setup, path: str | os.PathLike[str]) -> None:
    """Writes the setup to the JSON file ``path`` and its meshes and map to
    ``<stem>.parts/`` beside it (replacing both if they exist); see the module docstring.
    On any error nothing is left half-written. (``self``: this is ``Setup.save``.)"""
    import trimesh

    setup = self

    path = os.path.abspath(os.fspath(path))
    folder, base = os.path.split(path)
    stem = os.path.splitext(base)[0]
    parts_name = f"{stem}.parts"
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"{path}: its folder does not exist")
    scene, camera, envmap = setup.scene, setup.camera, setup.envmap
    tris, ids, names = scene.triangles(), scene.object_ids(), scene.object_names()
    lights = set(scene.area_lights())
    work = tempfile.mkdtemp(prefix=f".{stem}.", dir=folder)
    try:
        os.mkdir(os.path.join(work, parts_name))
        objects = []
        for k in range(scene.num_objects):
            t = tris[ids == k]
            if len(t) == 0:
                continue
            mesh_rel = f"{parts_name}/object{k}.ply"
            trimesh.Trimesh(t.reshape(-1, 3), np.arange(3 * len(t)).reshape(-1, 3),
                            process=False).export(os.path.join(work, mesh_rel))
            entry: dict[str, Any] = {"name": names[k], "mesh": mesh_rel,
                                     "material": _material_dict(scene.material(k))}
            if k in lights:
                entry["emission"] = list(scene.emission(k))
            objects.append(entry)
        env: dict[str, Any]
        if envmap.is_black:
            env = {"constant": [0.0, 0.0, 0.0], "resolution": envmap.resolution}
        else:
            env = {"file": f"{parts_name}/envmap.exr"}
            envmap.to_exr(os.path.join(work, env["file"]))
        c = camera
        doc = {"format": FORMAT, "version": VERSION, "name": setup.name, "objects": objects,
               "envmap": env,
               "camera": {"eye": list(c.eye), "forward": list(c.forward), "up": list(c.up),
                          "fov_deg": c.fov_deg, "width": c.width, "height": c.height}}
        with open(os.path.join(work, base), "w", encoding="utf-8") as f:
            f.write(_format(doc))
        # Everything is written: move it into place, the old parts aside first.
        target_parts = os.path.join(folder, parts_name)
        old = os.path.join(work, "old.parts")
        if os.path.exists(target_parts):
            os.replace(target_parts, old)
        os.replace(os.path.join(work, parts_name), target_parts)
        os.replace(os.path.join(work, base), path)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _format(doc: dict[str, Any]) -> str:
    """``doc`` as JSON with one line per field and per object, for people to read."""
    lines = []
    for k, v in doc.items():
        if k == "objects" and v:
            inner = ",\n".join("  " + json.dumps(o) for o in v)
            lines.append(f' "objects": [\n{inner}\n ]')
        else:
            lines.append(f" {json.dumps(k)}: {json.dumps(v)}")
    return "{\n" + ",\n".join(lines) + "\n}\n"


def load(path: str | os.PathLike[str]) -> Setup:
    """The :class:`Setup` a setup file describes (see the module docstring). A missing
    file raises FileNotFoundError; a file that is not such JSON, an unknown key, a bad
    value or a mesh that cannot be read raises ValueError naming the file and the key."""
    from .scene_files import load as load_mesh

    name = os.fspath(path)
    if not os.path.isfile(name):
        raise FileNotFoundError(f"{name}: no such setup file")
    try:
        with open(name, encoding="utf-8") as f:
            doc = json.load(f)
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{name}: not a JSON setup file ({e})") from e
    _check_keys(doc, _TOP_KEYS, name)
    if doc.get("format") != FORMAT or doc.get("version") != VERSION:
        raise ValueError(f"{name}: expected format {FORMAT!r} version {VERSION}, got "
                         f"{doc.get('format')!r} version {doc.get('version')!r}")
    base = os.path.dirname(os.path.abspath(name))

    def resolve(p: Any, where: str) -> str:
        if not isinstance(p, str):
            raise ValueError(f"{name}: {where}: expected a path, got {p!r}")
        return os.path.join(base, p)

    scene = Scene()
    objects = doc.get("objects", [])
    if not isinstance(objects, list):
        raise ValueError(f"{name}: objects: expected a list")
    for i, entry in enumerate(objects):
        where = f"{name}: objects[{i}]"
        _check_keys(entry, _OBJECT_KEYS, where)
        if "mesh" not in entry:
            raise ValueError(f"{where}: needs a 'mesh'")
        material = (_material(entry["material"], f"{where}.material")
                    if "material" in entry else None)
        try:
            part = load_mesh(resolve(entry["mesh"], f"objects[{i}].mesh"))
        except (FileNotFoundError, ValueError) as e:
            raise type(e)(f"{where}.mesh: {e}") from e
        label = entry.get("name")
        tris, ids, part_names = part.triangles(), part.object_ids(), part.object_names()
        for k in range(part.num_objects):
            t = tris[ids == k]
            if label is None:
                obj_name = part_names[k]
            else:
                obj_name = label if part.num_objects == 1 else f"{label}/{part_names[k]}"
            obj = scene.add_mesh(t.reshape(-1, 3), np.arange(3 * len(t)).reshape(-1, 3),
                                 material=material, name=obj_name)
            if "emission" in entry:
                try:
                    scene.set_emitter(obj, entry["emission"])
                except (TypeError, ValueError) as e:
                    raise ValueError(f"{where}.emission: {e}") from e
    envmap = _envmap(doc.get("envmap"), f"{name}: envmap", resolve)
    cam = _check_keys(doc.get("camera"), _CAMERA_KEYS, f"{name}: camera")
    try:
        eye = np.asarray(cam["eye"], np.float64)
        if "target" in cam:
            target = np.asarray(cam["target"], np.float64)
        else:
            target = eye + np.asarray(cam["forward"], np.float64)
        camera = Camera.look_at(eye, target, cam.get("up", (0, 1, 0)),
                                fov_deg=cam.get("fov_deg", 45.0), width=cam.get("width", 256),
                                height=cam.get("height", 192))
    except KeyError as e:
        raise ValueError(f"{name}: camera: needs {e.args[0]!r}") from None
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name}: camera: {e}") from e
    return Setup(scene, camera, envmap, name=doc.get("name"))


def _envmap(d: Any, where: str, resolve) -> EnvMap:
    if d is None:
        return EnvMap.constant(0.0)
    _check_keys(d, _ENVMAP_KEYS, where)
    try:
        if "file" in d and "constant" not in d:
            return EnvMap.from_exr(resolve(d["file"], "envmap.file"), d.get("resolution"))
        if "constant" in d and "file" not in d:
            return EnvMap.constant(d["constant"], d.get("resolution", 256))
    except FileNotFoundError as e:
        raise FileNotFoundError(f"{where}: {e}") from e
    except (TypeError, ValueError, OSError) as e:
        raise ValueError(f"{where}: {e}") from e
    raise ValueError(f"{where}: needs one of 'file' and 'constant'")
