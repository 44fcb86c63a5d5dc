"""Built-in procedural scenes, generated in Rust from a seed, and the benchmark suite.

==========  ===========  =======  ===========================================================
name        triangles    blocked  purpose
==========  ===========  =======  ===========================================================
cornell         1,262     0.87    closed Cornell box with two blocks, lit by its ceiling
                                  light: known-answer tests.
garage         11,636     0.78    building with a deep overhang, openings, ground and cars;
                                  the camera looks into the shadow, where most of the bright
                                  sky is occluded.
garden        402,332     0.83    ground covered by thin grass blades and a few tulips:
                                  near-random visibility, the hard case for reuse.
dynamics        6,768     0.01    a few objects on a large plane: little occlusion.
hairball    1,499,272     0.00    a dense tangle of thin tubes over a large plane.
instances     210,904     0.43    400 randomly rotated spheres, cylinders and boxes over a
                                  40 m ground.
strands       241,800     0.47    a stand of long, thin, leaning reeds (long thin triangles).
room           16,708     0.95    a closed room seen from inside, lit through its windows.
panels         64,010     0.61    four huge slanted panels (two triangles each) over small
                                  pebbles.
scales         29,152     0.12    a 1 km ground, far towers, and centimetre parts 0.5 m from
                                  the camera.
blob          330,880     0.31    one dense, closed, bumpy mesh on a ground.
meshes         66,214     0.23    six real public test meshes (teapot, spot, cow, fandisk,
                                  rocker arm, homer), each 1.5 m, on a 20 m ground; fetched
                                  on first use (see :func:`meshes`).
==========  ===========  =======  ===========================================================

Triangles are at ``detail=1``; ``detail`` in (0, 16] scales them roughly linearly.
"Blocked" is the fraction of shadow rays from points on the ground (the floor in ``room``,
the box's floor in ``cornell``) in uniform directions of the hemisphere that hit
something (``vc.testing.ground_hemisphere_rays``, 200,000 rays): together the scenes span
almost open to almost closed. :func:`names` lists the procedural scenes, :func:`suite_names`
the whole benchmark suite: the twelve above.

Variants for indirect light (``variants(name)``; ``load(name, variant=...)``): beside the
scenes above, which stay exactly as they are (``names()`` and ``suite_names()`` do not list
variants), a few scenes have named variants. :func:`indirect_names` lists the setups meant
for indirect light as ``(name, variant)`` pairs (variant None: the default setup). The
indirect share is the image mean of ``render(setup, camera=setup.camera.with_resolution(128,
96), method="path", bounces=3, direct=False, spp=256)`` over that with ``direct=True``
(standard errors at most 0.0022; ``python benches/indirect_share.py``):

==========  ==================  ================================================  ========
name        variant             what it is for                                    indirect
==========  ==================  ================================================  ========
cornell     (default)           colour bleeding: the red and green walls tint     0.40
                                the white floor and blocks
cornell     glossy_floor        the floor is Phong, exponent 50 (VF's glossy      0.41
                                Cornell box, ``N_s = 50``); all else as default
cornell     semiglossy_floor    the floor is Phong, exponent 10 (``N_s = 10``)    0.41
garage      (default)           windows map, no sun: the walls are lit directly   0.30
garage      sun                 a low sun (azimuth 180, elevation 15 deg) under   0.29
                                the roof's edge lights a floor patch inside;
                                walls and roof underside get only its bounce
                                and the sky
room        sunlit              the sun (azimuth 350, elevation 45 deg) falls     0.70
                                through the back windows; the camera, turned
                                away from them, sees neither windows nor sun
                                patches: indirect light dominates
==========  ==================  ================================================  ========

One variant is not for indirect light: ``load("garage", variant="ceiling_lights")`` is the
garage at night (a dim constant map) lit by 1,000 small area lights under the roof (radiances
between 0.25x and 1.75x of their mean): the many-light case of the survey's ch. 6. Nor is
``load("cornell", variant="dense_blocks")``: the blocks become closed bumpy ellipsoids of
81,920 triangles each (164,814 in all), the dense objects that BLD's proxies stand for.

``setup.variant`` names the variant (None for the default).

Animated variants (``animated_names()``; ``load("dynamics", animated=True)``): the
``dynamics`` sphere rolls 2 m toward the open ground and back every 60 frames.
``setup.at_frame(i)`` moves it (frame 0 is the static scene), ``setup.moving_object`` is its
object id and ``setup.moving_bounds()`` its bounds at the current frame.
"""

import os
from pathlib import Path

import numpy as np

from . import models
from ._core import (
    Scene,
    Setup,
    animated_scene_names,
    indirect_scene_names,
    load_scene,
    scene_names,
    scene_variants,
)

__all__ = ["MODEL_NAMES", "Setup", "animated_names", "indirect_names", "load", "meshes",
           "models_dir", "names", "read_obj", "suite_names", "variants", "without"]

#: The real meshes that :func:`meshes` arranges, in order (:mod:`viscache_rs.models`).
MODEL_NAMES = models.NAMES


def names() -> list[str]:
    """Names of the built-in scenes."""
    return list(scene_names())


def animated_names() -> list[str]:
    """Names of the built-in scenes that have an animated variant."""
    return list(animated_scene_names())


def variants(name: str) -> list[str]:
    """Names of the variants of the built-in scene ``name`` for ``load(name, variant=...)``
    (possibly none; ``"meshes"`` has none). An unknown name raises ValueError."""
    if name == "meshes":
        return []
    return list(scene_variants(name))


def indirect_names() -> list[tuple[str, str | None]]:
    """The setups for indirect light, as ``(name, variant)`` pairs for
    ``load(name, variant=variant)`` (variant None: the default setup); see the module's
    table."""
    return list(indirect_scene_names())


def suite_names() -> list[str]:
    """The benchmark suite: every procedural scene (:func:`names`), then ``"meshes"``, whose
    real meshes come from a local folder or are downloaded on first use
    (:mod:`viscache_rs.models`)."""
    return names() + ["meshes"]


def models_dir(path=None, required: bool = True) -> Path | None:
    """The local folder of the real meshes (:func:`viscache_rs.models.local_dir`): ``path``
    if given, else ``$VISCACHE_MODELS``, else ``../shared/models`` from the current
    directory or from the package's source tree. A folder counts when it holds the six
    models (``NAME.obj.gz`` or ``NAME.obj``). Raises FileNotFoundError naming every place
    looked at (or returns None when ``required`` is False). Without one, :func:`meshes`
    downloads the models instead."""
    return models.local_dir(path, required=required)


def meshes(models_dir_path=None, seed: int = 0) -> Setup:
    """The six real meshes of :data:`MODEL_NAMES` on a ground: each scaled so its largest
    side is 1.5 m, standing on the ground (its lowest point at y = 0) on a ring of radius
    2.2 m around (0, 0, -1), turned by a random yaw (``seed``); the ground is 20 x 20 m (40 x
    40 cells). The camera looks down at the ring from (0, 2.4, 4.6); the environment is the
    daylight of the procedural scenes (sun at azimuth 120 deg, elevation 40 deg).

    The models (vertices and faces only) are read from ``models_dir_path`` if given (which
    must hold them), else from the local folder of :func:`models_dir` when there is one,
    else from the user's cache folder, where the first call downloads them (about 2.1 MB,
    each file checked by SHA-256; :func:`viscache_rs.models.fetch`). Without network and
    without a local folder, OSError says how to get them by hand."""
    if models_dir_path is not None:
        models.local_dir(models_dir_path, required=True)
    scene = Scene()
    n = 40
    ax = np.linspace(-10.0, 10.0, n + 1, dtype=np.float32)
    gx, gz = np.meshgrid(ax, ax)
    verts = np.stack([gx.ravel(), np.zeros(gx.size, np.float32), gz.ravel()], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                            np.stack([a, c, d], -1).reshape(-1, 3)])
    scene.add_mesh(verts, faces, material=_lambert((0.55, 0.55, 0.5)), name="ground")
    albedos = [(0.7, 0.7, 0.72), (0.8, 0.6, 0.4), (0.45, 0.3, 0.2), (0.3, 0.45, 0.7),
               (0.6, 0.6, 0.55), (0.85, 0.75, 0.2)]
    rng = np.random.default_rng(seed)
    for k, name in enumerate(MODEL_NAMES):
        with models.open_model(name, models_dir_path) as stream:
            vertices, faces = read_obj(stream)
        v = vertices.astype(np.float64)
        v = (v - v.mean(axis=0)) * (1.5 / np.ptp(v, axis=0).max())
        yaw = rng.uniform(0, 2 * np.pi)
        rot = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
        v = v @ rot.T
        angle = 2 * np.pi * k / len(MODEL_NAMES)
        v += np.array([2.2 * np.sin(angle), -v[:, 1].min(), 2.2 * np.cos(angle) - 1.0])
        material = (_phong(albedos[k]) if name in ("teapot", "fandisk", "rocker-arm")
                    else _lambert(albedos[k]))
        scene.add_mesh(v.astype(np.float32), faces, material=material, name=name)
    from ._core import Camera
    from .envmaps import sky

    camera = Camera.look_at((0.0, 2.4, 4.6), (0.0, 0.4, -1.0), fov_deg=50.0, width=256,
                            height=192)
    el, az = np.radians(40.0), np.radians(120.0)
    env = sky(sun_dir=(np.cos(el) * np.sin(az), np.sin(el), -np.cos(el) * np.cos(az)))
    return Setup(scene, camera, env, name="meshes")


def read_obj(stream) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (N, 3) and triangles (M, 3) of a Wavefront OBJ file: ``stream`` is a path or
    a file opened for bytes or text. ``v`` and ``f`` lines only, polygons fanned into
    triangles, ``v/vt/vn``, negative indices and ``v x y z w`` understood.

    Raises ValueError naming the file (its ``name``, else ``stream``) and the line of
    anything malformed: text that is not UTF-8, a vertex without three finite coordinates,
    a face of fewer than three vertices (as in a file cut mid-face) or with an index that
    is not an integer or names an element the file does not have; and, naming the file, a
    file without a single face."""
    if isinstance(stream, (str, os.PathLike)):
        with open(stream, "rb") as f:
            return read_obj(f)
    source = str(getattr(stream, "name", "stream"))
    lines = _obj_lines(stream, source)
    kinds = {"v": 0, "vt": 1, "vn": 2}
    total = [0, 0, 0]
    for _, parts in lines:
        if parts[0] in kinds:
            total[kinds[parts[0]]] += 1
    seen = [0, 0, 0]
    vertices: list[list[float]] = []
    faces: list[list[int]] = []
    for number, parts in lines:
        def bad(reason: str, number: int = number) -> ValueError:
            return ValueError(f"{source}: line {number}: {reason}")

        words = _until_comment(parts[1:])
        if parts[0] == "v":
            vertices.append(_obj_vertex(words, bad))
        if parts[0] in kinds:
            seen[kinds[parts[0]]] += 1
        elif parts[0] == "f":
            if len(words) < 3:
                raise bad(f"a face needs at least 3 vertices, got {len(words)}")
            idx = [_obj_corner(w, seen, total, bad) for w in words]
            faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    if not faces:
        raise ValueError(f"{source}: no faces: the file holds no triangles "
                         "(is it an OBJ file?)")
    return np.asarray(vertices, np.float64).reshape(-1, 3), np.asarray(faces, np.int64)


def _obj_lines(stream, source: str) -> list[tuple[int, list[str]]]:
    """The non-blank lines of an OBJ stream as (line number, words), decoded as UTF-8."""
    out = []
    number = 0
    iterating = True
    try:
        for number, raw in enumerate(stream, 1):
            iterating = False
            line = raw.decode("utf-8") if isinstance(raw, bytes) else raw
            iterating = True
            parts = line.split()
            if parts:
                out.append((number, parts))
    except UnicodeDecodeError as e:
        # A text stream decodes ahead of the lines it returns: the bad byte lies after them.
        where = f"after line {number}" if iterating else f"line {number}"
        raise ValueError(f"{source}: {where}: not UTF-8 text (an OBJ file is text)") from e
    return out


def _until_comment(words: list[str]) -> list[str]:
    for k, w in enumerate(words):
        if w.startswith("#"):
            return words[:k]
    return words


def _obj_vertex(words: list[str], bad) -> list[float]:
    if len(words) not in (3, 4, 6):
        raise bad(f"a vertex needs 3 coordinates (4 with w, 6 with a colour), got {len(words)}")
    values: list[float] = []
    for word in words[:4] if len(words) == 4 else words[:3]:
        try:
            x = float(word)
        except ValueError as e:
            raise bad(f"vertex coordinate {word!r} is not a number") from e
        if not np.isfinite(x) or (len(values) == 3 and x == 0.0):
            raise bad(f"vertex coordinate {word} is not finite" if len(values) < 3
                      else "vertex w is 0")
        values.append(x)
    scale = values[3] if len(values) == 4 else 1.0
    return [x / scale for x in values[:3]]


def _obj_corner(word: str, seen: list[int], total: list[int], bad) -> int:
    """The 0-based vertex index of a face's corner ``v``, ``v/vt``, ``v//vn`` or ``v/vt/vn``;
    positive indices may point forward (judged against the file's totals), negative ones
    count back from the last element before the face."""
    parts = word.split("/")
    if len(parts) > 3 or not parts[0]:
        raise bad(f"face vertex {word!r} is not v, v/vt, v//vn or v/vt/vn")
    names = ("vertex", "texture coordinate", "normal")
    plural = ("vertices", "texture coordinates", "normals")
    out = 0
    for k, part in enumerate(parts):
        if not part:
            continue
        try:
            index = int(part)
        except ValueError as e:
            raise bad(f"{names[k]} index {part!r} is not an integer") from e
        have = seen[k] if index < 0 else total[k]
        if index == 0 or abs(index) > have:
            before = " before this line" if index < 0 else ""
            raise bad(f"{names[k]} index {index} does not exist (OBJ indices start at 1; "
                      f"the file has {have} {plural[k]}{before})")
        if k == 0:
            out = index - 1 if index > 0 else seen[0] + index
    return out


def _lambert(albedo):
    from ._core import Material

    return Material.lambert(albedo)


def _phong(albedo):
    from ._core import Material

    kd = tuple(0.6 * c for c in albedo)
    return Material.phong(kd, (0.3, 0.3, 0.3), 50.0)


def load(name: str, detail: float = 1.0, seed: int = 0, animated: bool = False,
         variant: str | None = None) -> Setup:
    """Builds the built-in scene ``name`` (``"meshes"``: :func:`meshes`, whose triangles
    ``detail`` does not change).

    Returns a :class:`Setup` with ``.scene``, ``.camera`` (256x192 by default; use
    ``setup.camera.with_resolution(w, h)`` for other sizes) and ``.envmap``, the scene's
    default :class:`EnvMap` (sky and sun for garden, dynamics and hairball; bright windows
    mostly hidden by the roof for garage; constant white for the closed cornell box). The
    same ``seed`` always gives the same triangles.

    ``animated=True`` gives the animated variant (only for :func:`animated_names`; other
    names raise ValueError naming ``animated``): at frame 0 it is the same scene; move it
    with ``setup.at_frame(i)``.

    ``variant`` names one of :func:`variants` (``name``): the variants for indirect light of
    the module's table. Unknown variants raise ValueError naming ``variant`` and listing the
    scene's variants; so does a variant with ``animated=True``.
    """
    if name == "meshes" and not animated:
        if variant is not None:
            raise ValueError(f"variant: scene 'meshes' has no variants, got {variant!r}")
        return meshes(seed=seed)
    return load_scene(name, detail=detail, seed=seed, animated=animated, variant=variant)


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
