"""Mitsuba 3 scenes read into a :class:`Setup` (:func:`viscache_rs.mitsuba.from_mitsuba`).

Mitsuba's own loader reads the scene (XML, with its includes, defaults, transforms and mesh
formats, or a ``load_dict`` dict) in the ``scalar_rgb`` variant; the loaded objects are then
read back through what they expose: each shape's world-space buffers, its BSDF and emitter,
the scene's emitters and first sensor, and each object's direct children (a traversal
callback that records them, as ``mi.traverse`` would before flattening). Only what has an
exact counterpart here is accepted; anything else raises ValueError naming the plugin, its
id and the scene.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from ._core import Camera, EnvMap, Material, Scene, Setup
from .octahedral import square_to_sphere

#: Mitsuba's class names (``obj.class_name()``) of its plugins, by which errors name the
#: plugin as a scene file does; a class not listed is named by its class.
PLUGIN_OF_CLASS = {
    # BSDFs
    "SmoothDiffuse": "diffuse", "TwoSidedBRDF": "twosided", "RoughPlastic": "roughplastic",
    "SmoothPlastic": "plastic", "SmoothConductor": "conductor",
    "RoughConductor": "roughconductor", "SmoothDielectric": "dielectric",
    "RoughDielectric": "roughdielectric", "ThinDielectric": "thindielectric",
    "Principled": "principled", "PrincipledThin": "principledthin", "MaskBSDF": "mask",
    "BlendBSDF": "blendbsdf", "BumpMap": "bumpmap", "NormalMap": "normalmap",
    "Null": "null", "PolarizedPlastic": "pplastic", "Hair": "hair", "Measured": "measured",
    # shapes
    "OBJMesh": "obj", "PLYMesh": "ply", "SerializedMesh": "serialized", "Cube": "cube",
    "Rectangle": "rectangle", "Sphere": "sphere", "Disk": "disk", "Cylinder": "cylinder",
    "ShapeGroupPlugin": "shapegroup", "Instance": "instance",
    # emitters
    "AreaLight": "area", "ConstantBackgroundEmitter": "constant",
    "EnvironmentMapEmitter": "envmap", "PointLight": "point", "SpotLight": "spot",
    "DirectionalEmitter": "directional", "SunskyEmitter": "sunsky", "Projector": "projector",
    # sensors
    "PerspectiveCamera": "perspective", "ThinLensCamera": "thinlens",
    "OrthographicCamera": "orthographic", "IrradianceMeter": "irradiancemeter",
    "RadianceMeter": "radiancemeter",
    # textures with one value (the only ones accepted)
    "UniformSpectrum": "uniform", "SRGBReflectanceSpectrum": "rgb",
    "SRGBEmitterSpectrum": "rgb", "BitmapTexture": "bitmap", "Checkerboard": "checkerboard",
}

#: Shapes whose triangles Mitsuba holds in world space (``vertex_positions_buffer``).
MESH_SHAPES = {"obj", "ply", "serialized", "cube", "rectangle"}

#: Samples per texel side when an ``envmap`` is read into an octahedral map: each texel is
#: the mean of ``4 x 4`` evaluations of Mitsuba's emitter on a stratified grid, which keeps
#: them an eighth of a texel inside its edges, where the lat-long image that
#: ``to_mitsuba`` writes (sixteen pixels per texel width) is not blurred across them.
ENV_SAMPLES_PER_SIDE = 4


def plugin_name(obj) -> str:
    """The plugin name of a loaded Mitsuba object, e.g. ``"roughplastic"``."""
    # class_name() since Mitsuba 3.6 (or so); class_().name() before.
    cls = obj.class_name() if hasattr(obj, "class_name") else obj.class_().name()
    return PLUGIN_OF_CLASS.get(cls, cls)


class _Unsupported(ValueError):
    pass


def _describe(obj) -> str:
    oid = obj.id()
    return f"plugin {plugin_name(obj)!r}" + (f" (id {oid!r})" if oid else "")


def _children(mi, obj) -> dict[str, Any]:
    """``obj``'s direct children and parameters by name, as its ``traverse`` reports them."""

    class Children(mi.TraversalCallback):
        def __init__(self) -> None:
            super().__init__()
            self.found: dict[str, Any] = {}

        def put(self, name, value, flags, *rest):
            self.found[name] = value

        # Mitsuba before 3.7 calls these instead of put.
        put_parameter = put_value = put_object = put

    cb = Children()
    obj.traverse(cb)
    return cb.found


def _uniform_rgb(mi, texture, what: str) -> tuple[float, float, float]:
    """The one RGB value of a uniform or ``rgb`` texture; any other raises."""
    if plugin_name(texture) not in ("uniform", "rgb"):
        raise _Unsupported(f"{what}: {_describe(texture)} varies over the surface; only a "
                           "constant value (a number or 'rgb') has a counterpart here")
    value = np.array(mi.traverse(texture)["value"], dtype=np.float64).ravel()
    rgb = np.broadcast_to(value, 3) if value.size == 1 else value
    return (float(rgb[0]), float(rgb[1]), float(rgb[2]))


def _material(mi, bsdf, phong_class) -> Material:
    name = plugin_name(bsdf)
    if name == "twosided":
        kids = _children(mi, bsdf)
        sides = [_material(mi, kids[k], phong_class) for k in ("brdf_0", "brdf_1") if k in kids]
        if len(sides) == 2 and (sides[0].kind != sides[1].kind
                                or sides[0].params() != sides[1].params()):
            raise _Unsupported(f"BSDF {_describe(bsdf)} has two different sides; ours "
                               "shade both sides alike")
        return sides[0]
    if name == "diffuse":
        kids = _children(mi, bsdf)
        return Material.lambert(_uniform_rgb(mi, kids["reflectance"],
                                             f"reflectance of {_describe(bsdf)}"))
    if phong_class is not None and isinstance(bsdf, phong_class):
        return Material.phong(np.array(bsdf.kd, float), np.array(bsdf.ks, float), bsdf.e)
    raise _Unsupported(f"BSDF {_describe(bsdf)} has no exact counterpart here (supported: "
                       "diffuse, twosided, viscache_phong)")


def _triangles(mi, shape, sphere_subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """World-space vertices (V, 3) and faces (F, 3) of a supported shape, wound so that
    their winding normal is Mitsuba's normal (which ``flip_normals`` turns over): the side
    an area light emits on, here and there."""
    vertices, faces = _untransformed_triangles(mi, shape, sphere_subdivisions)
    if getattr(shape, "has_flipped_normals", lambda: False)():
        faces = faces[:, ::-1]
    return vertices, faces


def _untransformed_triangles(mi, shape, sphere_subdivisions: int):
    name = plugin_name(shape)
    if shape.is_mesh() and (name in MESH_SHAPES or name == "Mesh"):
        vertices = np.array(shape.vertex_positions_buffer(), np.float32).reshape(-1, 3)
        faces = np.array(shape.faces_buffer(), np.int64).reshape(-1, 3)
        return vertices, faces
    if name == "sphere":
        import trimesh

        # Mitsuba's sphere is the unit sphere under to_world (centre and radius folded in).
        ball = trimesh.creation.icosphere(subdivisions=sphere_subdivisions)
        m = np.array(mi.traverse(shape)["to_world"].matrix, np.float64)
        vertices = ball.vertices @ m[:3, :3].T + m[:3, 3]
        return vertices.astype(np.float32), np.asarray(ball.faces, np.int64)
    raise _Unsupported(f"shape {_describe(shape)} has no counterpart here (supported: "
                       "obj, ply, serialized, cube, rectangle, sphere)")


def _camera(mi, sensor) -> Camera:
    if plugin_name(sensor) != "perspective":
        raise _Unsupported(f"sensor {_describe(sensor)}: only 'perspective' has a "
                           "counterpart here (a pinhole camera)")
    p = mi.traverse(sensor)
    for k in ("principal_point_offset_x", "principal_point_offset_y"):
        if k in p and float(p[k]) != 0.0:
            raise _Unsupported(f"sensor {_describe(sensor)}: {k} = {float(p[k])}; our "
                               "camera looks through the centre of its image")
    film = sensor.film()
    width, height = (int(v) for v in film.size())
    if [int(v) for v in film.crop_size()] != [width, height]:
        raise _Unsupported(f"sensor {_describe(sensor)}: its film has a crop window; our "
                           "camera renders the whole image")
    m = np.array(p["to_world"].matrix, np.float64)
    axes = m[:3, :3]  # columns: Mitsuba's camera x (to the image's left), up, forward
    if not np.allclose(axes.T @ axes, np.eye(3), atol=1e-4) or np.linalg.det(axes) < 0:
        raise _Unsupported(f"sensor {_describe(sensor)}: to_world scales, shears or "
                           "mirrors the view; only rotations and translations have a "
                           "counterpart here")
    x_fov = math.radians(float(p["x_fov"]))
    y_fov = 2.0 * math.atan(math.tan(0.5 * x_fov) * height / width)
    eye = m[:3, 3]
    return Camera.look_at(eye, eye + axes[:, 2], axes[:, 1], fov_deg=math.degrees(y_fov),
                          width=width, height=height)


def _env_texels(mi, emitter, resolution: int) -> np.ndarray:
    """Octahedral texels (R, R, 3): the mean of Mitsuba's emitter over each texel, from
    ``ENV_SAMPLES_PER_SIDE``² stratified evaluations (its ``to_world`` and ``scale``
    included, as it renders them)."""
    k = ENV_SAMPLES_PER_SIDE
    n = resolution * k
    t = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(t, t, indexing="xy")  # texels[row = v, col = u]
    dirs = square_to_sphere(np.stack([u.ravel(), v.ravel()], -1).astype(np.float32))
    si = mi.SurfaceInteraction3f()
    vector, evaluate = mi.Vector3f, emitter.eval
    values = []
    # About 3 us an evaluation (1M for the default 256² texels: 3 s); a plain loop, so
    # Ctrl-C stops it between two.
    for x, y, z in (-dirs.astype(np.float64)).tolist():
        # eval takes the direction the light travels in, toward the scene.
        si.wi = vector(x, y, z)
        values.append(tuple(evaluate(si))[:3])
    out = np.array(values, np.float64)
    return out.reshape(resolution, k, resolution, k, 3).mean(axis=(1, 3)).astype(np.float32)


def _load(mi, source) -> tuple[Any, str]:
    arg: Any
    if isinstance(source, dict):
        label = "the dict"
        if source.get("type") != "scene":
            raise ValueError("source: a Mitsuba scene dict needs type 'scene', got "
                             f"{source.get('type')!r}")
        loader, arg = mi.load_dict, source
    elif isinstance(source, str | os.PathLike):
        label = os.fspath(source)
        if not os.path.isfile(label):
            raise FileNotFoundError(f"{label}: no such Mitsuba scene file")
        loader, arg = mi.load_file, label
    else:
        raise TypeError("source: expected a path to a Mitsuba XML file or a load_dict dict, "
                        f"got {type(source).__name__}")
    try:
        try:
            # Mitsuba 3.7+ merges meshes that share a BSDF unless told not to; objects
            # must stay apart here.
            scene = loader(arg, optimize=False)
        except TypeError:
            scene = loader(arg)
    except Exception as e:  # Mitsuba raises RuntimeError for every parse/plugin error
        raise ValueError(f"{label}: Mitsuba cannot load it: {e}") from e
    if not isinstance(scene, mi.Scene):
        raise ValueError(f"{label}: holds a {plugin_name(scene)}, not a scene")
    return scene, label


def read(source, envmap_resolution: int = 256, sphere_subdivisions: int = 4) -> Setup:
    """See :func:`viscache_rs.mitsuba.from_mitsuba`."""
    from . import mitsuba as vmi

    if not isinstance(envmap_resolution, int) or not 2 <= envmap_resolution <= 4096:
        raise ValueError(f"envmap_resolution: must be an int in [2, 4096], got "
                         f"{envmap_resolution!r}")
    if not isinstance(sphere_subdivisions, int) or not 0 <= sphere_subdivisions <= 7:
        raise ValueError(f"sphere_subdivisions: must be an int in [0, 7], got "
                         f"{sphere_subdivisions!r}")
    mi = vmi._import_mitsuba()
    with vmi._scalar_variant(mi):
        vmi._register_phong(mi)
        phong_class = vmi._phong_classes.get(mi.variant())
        mi_scene, label = _load(mi, source)
        try:
            return _setup(mi, mi_scene, phong_class, envmap_resolution, sphere_subdivisions)
        except _Unsupported as e:
            raise ValueError(f"{label}: {e}") from None


def _setup(mi, mi_scene, phong_class, envmap_resolution, sphere_subdivisions) -> Setup:
    scene = Scene()
    for shape in mi_scene.shapes():
        vertices, faces = _triangles(mi, shape, sphere_subdivisions)
        try:
            material = _material(mi, shape.bsdf(), phong_class)
        except _Unsupported as e:
            raise _Unsupported(f"shape {_describe(shape)}: {e}") from None
        name = shape.id() or None
        obj = scene.add_mesh(vertices, faces, material=material, name=name)
        emitter = shape.emitter()
        if emitter is not None:
            if plugin_name(emitter) != "area":
                raise _Unsupported(f"shape {_describe(shape)}: emitter {_describe(emitter)}")
            radiance = _uniform_rgb(mi, _children(mi, emitter)["radiance"],
                                    f"radiance of {_describe(emitter)}")
            scene.set_emitter(obj, radiance)
    texels = np.zeros((envmap_resolution, envmap_resolution, 3), np.float32)
    for emitter in mi_scene.emitters():
        kind = plugin_name(emitter)
        if kind == "area":
            continue  # read with its shape
        if kind == "constant":
            rgb = _uniform_rgb(mi, _children(mi, emitter)["radiance"],
                               f"radiance of {_describe(emitter)}")
            texels += np.asarray(rgb, np.float32)
        elif kind == "envmap":
            texels += _env_texels(mi, emitter, envmap_resolution)
        else:
            raise _Unsupported(f"emitter {_describe(emitter)} has no counterpart here "
                               "(supported: area, constant, envmap)")
    sensors = mi_scene.sensors()
    if not sensors:
        raise _Unsupported("no sensor: a 'perspective' sensor gives the camera")
    camera = _camera(mi, sensors[0])
    return Setup(scene, camera, EnvMap.from_octahedral(texels), name="mitsuba")
