"""Setups as Mitsuba 3 scenes and back, to render the same image with the renderer a user
would otherwise pick (``pip install mitsuba``; the peer benchmark ``benches/peer_mitsuba.py``
and the cross-validation test use it), and to bring scenes kept for Mitsuba here.

``to_mitsuba(setup, camera=None, envmap=None, spp=8, equirect_width=None,
integrator="direct", max_depth=None)`` returns a dict for ``mitsuba.load_dict``;
``load(setup, ...)`` loads it; ``from_mitsuba(path_or_dict)`` reads a Mitsuba scene (XML
file or dict) into a :class:`~viscache_rs.Setup` with Mitsuba's own loader, refusing by
name what has no exact counterpart here (see its docstring). The conversion keeps what our
renderer computes:

- one mesh per object, without vertex normals (both shade with geometric normals);
- Lambert as ``twosided`` ``diffuse``; the normalised Phong BRDF
  (``f = kd / pi + ks (e + 2) / (2 pi) cos^e alpha``) as the ``viscache_phong`` plugin
  registered here, in ``twosided`` (our shading normal faces the viewer, as ``twosided``
  does); its sampling is ours: the lobe chosen by its luminance share, cosine-weighted
  diffuse directions, ``cos^e`` about the mirror direction;
- the environment map as ``envmap`` from ``EnvMap.to_equirect(w, w / 2)`` (Mitsuba's lat-long
  convention is ours: ``u = atan2(x, -z) / 2 pi``, ``v = acos(y) / pi``, +y up), seen by the
  camera, its rows moved to the latitudes Mitsuba reads them at
  (:func:`rows_at_mitsubas_latitudes`: its first and last rows lie on the poles). ``w``
  defaults to :func:`equirect_width_for` the map: about sixteen pixels per texel width,
  because Mitsuba interpolates the image bilinearly and a daylight map's shadows converge
  only there (measured on ``panels`` before the rows were moved: the ground's mean moved by
  -0.14% from 4096 to 16384 pixels wide, and by 0.03% (1.4 SE) from 8192 to 16384);
- area lights as ``area`` emitters on their triangles (one-sided, on the side of the winding
  normal, in both renderers) with a black BSDF;
- the pinhole camera as ``perspective`` with ``fov_axis="y"``, an ``hdrfilm`` of its size
  with a ``box`` filter, and the ``direct`` integrator (one emitter and one BSDF sample per
  pixel sample, MIS) or the ``path`` tracer (``max_depth`` 3: one bounce) with the
  ``independent`` sampler.

What cannot be kept: Mitsuba offsets rays leaving a surface by ``(1 + max|p|) 8.9e-5``
(0.13 mm half a metre from the origin), ours by 64 ulps of the hit triangle's coordinates
(4 µm there). Where occluders lie within a fraction of a millimetre of the surfaces they
shade (``scales``' centimetre parts standing side by side), Mitsuba's shadow rays start past
some of them: a quadrature of the parts' pixels with our rays gives our render's mean to
1e-4, with Mitsuba's offsets 0.4% more light.

Mitsuba needs a variant chosen before ``to_mitsuba`` is called (``mitsuba.set_variant``):
``scalar_rgb`` works anywhere; ``llvm_ad_rgb`` (fast) needs LLVM (Debian's ``libllvm19``:
``scripts/install-llvm.sh``; without it, choosing the variant aborts the process, which
:func:`llvm_available` finds out in a child process). ``from_mitsuba`` needs no variant.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import subprocess
import sys
import tempfile
from typing import Any

import numpy as np

from .metrics import LUMINANCE

__all__ = ["INTEGRATORS", "MAX_EQUIRECT_WIDTH", "PHONG_PLUGIN", "equirect_width_for",
           "from_mitsuba", "llvm_available", "load", "render", "rows_at_mitsubas_latitudes",
           "to_mitsuba"]

#: Widest lat-long image :func:`equirect_width_for` chooses.
MAX_EQUIRECT_WIDTH = 8192

#: Name of the normalised Phong BSDF plugin registered by :func:`to_mitsuba`.
PHONG_PLUGIN = "viscache_phong"

#: The Phong plugin's class per variant it was registered for (the importer recognises
#: the plugin's objects by it).
_phong_classes: dict[str, type] = {}

#: Integrators :func:`to_mitsuba` writes.
INTEGRATORS = ("direct", "path")


def _import_mitsuba():
    try:
        import mitsuba as mi
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError(
            "viscache_rs.mitsuba needs Mitsuba 3: pip install mitsuba "
            "(or the 'experiments' extra)"
        ) from e
    return mi


def _mi():
    mi = _import_mitsuba()
    if mi.variant() is None:
        raise RuntimeError(
            "choose a Mitsuba variant first, e.g. mitsuba.set_variant('scalar_rgb') or "
            "'llvm_ad_rgb'"
        )
    return mi


#: What :func:`llvm_available` runs in a child process: a render, because an LLVM older
#: than Dr.Jit's (Debian 12's libLLVM-15) loads and compiles small kernels, then aborts
#: the process on a renderer's.
_LLVM_PROBE = """
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
look = mi.ScalarTransform4f().look_at(origin=[0, 1, 4], target=[0, 0, 0], up=[0, 1, 0])
scene = mi.load_dict({"type": "scene", "integrator": {"type": "direct"},
                      "box": {"type": "cube"},
                      "sky": {"type": "constant"},
                      "sensor": {"type": "perspective", "to_world": look,
                                 "film": {"type": "hdrfilm", "width": 4, "height": 4}}})
mi.render(scene, spp=1)
"""


@functools.cache
def llvm_available(timeout: float = 120.0) -> bool:
    """Whether Mitsuba's ``llvm_ad_rgb`` variant renders here (it needs LLVM 19 or newer,
    Debian's ``libllvm19``: ``scripts/install-llvm.sh``; ``DRJIT_LIBLLVM_PATH`` chooses
    among several). Found out in a child process, because choosing the variant without it
    aborts the process that does; the answer is kept for this process."""
    try:
        child = subprocess.run([sys.executable, "-c", _LLVM_PROBE], capture_output=True,
                               timeout=timeout)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return child.returncode == 0


@contextlib.contextmanager
def _scalar_variant(mi):
    """``scalar_rgb`` for the duration, the caller's variant (if any) after: the importer
    needs no LLVM and must not change what the caller renders with."""
    before = mi.variant()
    if before != "scalar_rgb":
        mi.set_variant("scalar_rgb")
    try:
        yield
    finally:
        if before is not None and before != "scalar_rgb":
            mi.set_variant(before)


def _register_phong(mi) -> None:
    """Registers the normalised Phong BSDF for the current variant (once per variant)."""
    if mi.variant() in _phong_classes:
        return
    import drjit as dr

    class NormalisedPhong(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.kd = mi.Color3f(props["kd"])
            self.ks = mi.Color3f(props["ks"])
            self.e = float(props["exponent"])
            self.ps = float(props["specular_probability"])
            self.m_components = [mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide,
                                 mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide]
            self.m_flags = self.m_components[0] | self.m_components[1]

        def _lobe_cos(self, wi, wo):
            # cos alpha between the light direction and the mirror of the view direction.
            mirror = mi.Vector3f(-wi.x, -wi.y, wi.z)
            return dr.dot(mirror, wo)

        def _eval_pdf(self, wi, wo, active):
            cos_i = mi.Frame3f.cos_theta(wi)
            cos_o = mi.Frame3f.cos_theta(wo)
            valid = active & (cos_i > 0) & (cos_o > 0)
            c = dr.maximum(self._lobe_cos(wi, wo), 0.0)
            lobe = dr.power(c, self.e)
            f = self.kd * dr.inv_pi + self.ks * ((self.e + 2.0) * dr.inv_two_pi * lobe)
            value = dr.select(valid, f * cos_o, 0.0)
            pdf = (1.0 - self.ps) * cos_o * dr.inv_pi + self.ps * (
                (self.e + 1.0) * dr.inv_two_pi * lobe)
            return value, dr.select(valid, pdf, 0.0)

        def sample(self, ctx, si, sample1, sample2, active=True):
            wi = si.wi
            specular = sample1 < self.ps
            diffuse_dir = mi.warp.square_to_cosine_hemisphere(sample2)
            cos_a = dr.power(sample2.x, 1.0 / (self.e + 1.0))
            sin_a = dr.safe_sqrt(1.0 - cos_a * cos_a)
            phi = dr.two_pi * sample2.y
            local = mi.Vector3f(sin_a * dr.cos(phi), sin_a * dr.sin(phi), cos_a)
            mirror = mi.Vector3f(-wi.x, -wi.y, wi.z)
            lobe_dir = mi.Frame3f(mirror).to_world(local)
            wo = dr.select(specular, lobe_dir, diffuse_dir)
            value, pdf = self._eval_pdf(wi, wo, active)
            bs = mi.BSDFSample3f()
            bs.wo = wo
            bs.pdf = pdf
            bs.eta = 1.0
            bs.sampled_component = dr.select(specular, mi.UInt32(1), mi.UInt32(0))
            bs.sampled_type = dr.select(
                specular, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                mi.UInt32(+mi.BSDFFlags.DiffuseReflection))
            ok = active & (pdf > 0)
            return bs, dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)

        def eval(self, ctx, si, wo, active=True):
            return self._eval_pdf(si.wi, wo, active)[0]

        def pdf(self, ctx, si, wo, active=True):
            return self._eval_pdf(si.wi, wo, active)[1]

        def eval_pdf(self, ctx, si, wo, active=True):
            return self._eval_pdf(si.wi, wo, active)

        def traverse(self, callback):
            # Nothing to differentiate; the importer reads kd, ks and e off the object.
            pass

        def to_string(self):
            return f"NormalisedPhong[e={self.e}]"

    mi.register_bsdf(PHONG_PLUGIN, lambda props: NormalisedPhong(props))
    _phong_classes[mi.variant()] = NormalisedPhong


def _bsdf(material) -> dict[str, Any]:
    p = material.params()
    if material.kind == "lambert":
        inner: dict[str, Any] = {"type": "diffuse",
                 "reflectance": {"type": "rgb", "value": [float(c) for c in p["albedo"]]}}
    else:
        kd = np.asarray(p["kd"], float)
        ks = np.asarray(p["ks"], float)
        d, s = float(kd @ LUMINANCE), float(ks @ LUMINANCE)
        inner = {"type": PHONG_PLUGIN, "kd": [float(c) for c in kd],
                 "ks": [float(c) for c in ks], "exponent": float(p["exponent"]),
                 "specular_probability": s / (d + s) if d + s > 0 else 0.0}
    return {"type": "twosided", "bsdf": inner}


def equirect_width_for(envmap) -> int:
    """The lat-long width :func:`to_mitsuba` exports ``envmap`` at by default: the power of
    two of at least sixteen pixels per texel width (a texel spans ``2 sqrt(pi) / R`` radians,
    so the equator holds ``sqrt(pi) R`` texels), at most 8192 (a 400 MB image)."""
    texels_around = math.sqrt(math.pi) * envmap.resolution
    return min(MAX_EQUIRECT_WIDTH, 1 << math.ceil(math.log2(16 * texels_around)))


def _integrator(integrator: str, max_depth: int | None) -> dict[str, Any]:
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator: expected one of {INTEGRATORS}, got {integrator!r}")
    if integrator == "direct":
        if max_depth is not None:
            raise ValueError("max_depth: the 'direct' integrator takes none (it stops after "
                             "the first bounce)")
        return {"type": "direct"}
    d: dict[str, Any] = {"type": "path"}
    if max_depth is not None:
        if (not isinstance(max_depth, int) or isinstance(max_depth, bool)
                or not (max_depth == -1 or max_depth >= 1)):
            raise ValueError(f"max_depth: must be -1 (no limit) or an int >= 1, got "
                             f"{max_depth!r}")
        d["max_depth"] = max_depth
    return d


def to_mitsuba(setup, camera=None, envmap=None, spp: int = 8,
               equirect_width: int | None = None,
               folder: str | os.PathLike[str] | None = None, integrator: str = "direct",
               max_depth: int | None = None) -> dict[str, Any]:
    """A ``mitsuba.load_dict`` dict of ``setup`` seen by ``camera`` (default: the setup's)
    under ``envmap`` (default: the setup's), the map exported ``equirect_width`` pixels
    wide (default: :func:`equirect_width_for` it); see the module docstring. The objects are
    written as PLY files into ``folder`` (default: a new temporary folder), which must exist
    until the dict is loaded; :func:`load` does this and removes them.

    ``integrator`` is ``"direct"`` (direct light only: one emitter and one BSDF sample per
    pixel sample, MIS) or ``"path"`` (Mitsuba's path tracer, to check the indirect
    methods). ``max_depth`` is the path tracer's longest path in segments from the camera,
    as Mitsuba counts them: 2 is direct light only, 3 adds one bounce (what
    ``render(..., method="path", bounces=1)`` computes), -1 or None no limit; the direct
    integrator takes none."""
    mi = _mi()
    if equirect_width is not None and (equirect_width < 2 or equirect_width % 2):
        raise ValueError(f"equirect_width: must be an even number >= 2, got {equirect_width}")
    integrator_dict = _integrator(integrator, max_depth)
    _register_phong(mi)
    camera = setup.camera if camera is None else camera
    envmap = setup.envmap if envmap is None else envmap
    if equirect_width is None:
        equirect_width = equirect_width_for(envmap)
    folder = tempfile.mkdtemp(prefix="viscache_mitsuba_") if folder is None else folder
    scene = setup.scene
    eye = np.asarray(camera.eye, float)
    d: dict[str, Any] = {
        "type": "scene",
        "integrator": integrator_dict,
        "sensor": {
            "type": "perspective",
            "fov": float(camera.fov_deg),
            "fov_axis": "y",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=eye.tolist(), target=(eye + np.asarray(camera.forward)).tolist(),
                up=list(camera.up)),
            "film": {"type": "hdrfilm", "width": camera.width, "height": camera.height,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": int(spp)},
        },
    }
    if not envmap.is_black:
        rgb = rows_at_mitsubas_latitudes(
            envmap.to_equirect(equirect_width, equirect_width // 2))
        d["environment"] = {"type": "envmap", "bitmap": mi.Bitmap(rgb)}
    tris = scene.triangles()
    ids = scene.object_ids()
    lights = set(scene.area_lights())
    for k in range(scene.num_objects):
        t = tris[ids == k]
        if len(t) == 0:
            continue
        path = os.path.join(folder, f"object{k}.ply")
        _write_ply(mi, t, path, f"object{k}")
        entry: dict[str, Any] = {"type": "ply", "filename": path, "face_normals": True}
        if k in lights:
            entry["bsdf"] = {"type": "diffuse",
                             "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}
            entry["emitter"] = {"type": "area", "radiance": {
                "type": "rgb", "value": [float(c) for c in scene.emission(k)]}}
        else:
            entry["bsdf"] = _bsdf(scene.material(k))
        d[f"object{k}"] = entry
    return d


def rows_at_mitsubas_latitudes(rgb: np.ndarray) -> np.ndarray:
    """``rgb``, a lat-long image whose row ``j`` is the mean over ``theta`` in ``[j, j + 1]
    pi / H`` (as ``EnvMap.to_equirect`` writes it), as the rows Mitsuba's ``envmap`` reads:
    it interpolates between rows placed at ``theta = pi y / (H - 1)``, the first at the
    north pole and the last at the south pole (its columns are at pixel centres, as
    ours). Each of its rows becomes the mean of our rows over its band ``theta`` in
    ``[y - 1/2, y + 1/2] pi / (H - 1)``, weighted by solid angle, so the sphere's power is
    kept. Given our rows as they are, Mitsuba reads a sun 35 degrees high about a fifth of
    a row nearer the pole, which moved the suite's image means by up to 0.07% at 8192
    pixels wide (``panels``, 10 s: 0.9994 of Mitsuba's before, 1.0001 after)."""
    h = rgb.shape[0]
    # Band edges as 1 - cos(theta), which grows from 0 at the north pole to 2 at the south
    # pole and measures solid angle per unit of azimuth.
    ours = 1.0 - np.cos(np.pi * np.arange(h + 1) / h)
    theirs = 1.0 - np.cos(np.pi * np.clip((np.arange(h + 1) - 0.5) / (h - 1), 0.0, 1.0))
    # Per band of Mitsuba's, the first and last of our rows it overlaps.
    first = np.searchsorted(ours, theirs[:-1], side="right") - 1
    last = np.searchsorted(ours, theirs[1:], side="left") - 1
    out = np.empty(rgb.shape, np.float32)
    for y in range(h):
        lo, hi = theirs[y], theirs[y + 1]
        acc = np.zeros(rgb.shape[1:], np.float64)
        for j in range(first[y], last[y] + 1):
            acc += (min(ours[j + 1], hi) - max(ours[j], lo)) * rgb[j]
        out[y] = acc / (hi - lo)
    return out


def _write_ply(mi, triangles: np.ndarray, path: str, name: str) -> None:
    vertices = np.ascontiguousarray(triangles.reshape(-1, 3), dtype=np.float32)
    faces = np.arange(len(vertices), dtype=np.uint32).reshape(-1, 3)
    mesh = mi.Mesh(name, vertex_count=len(vertices), face_count=len(faces),
                   has_vertex_normals=False, has_vertex_texcoords=False)
    params = mi.traverse(mesh)
    # The buffers' own types: flat arrays in every variant (mi.Float is a scalar in the
    # scalar ones).
    params["vertex_positions"] = type(params["vertex_positions"])(vertices.ravel())
    params["faces"] = type(params["faces"])(faces.ravel())
    params.update()
    mesh.write_ply(path)


def load(setup, camera=None, envmap=None, spp: int = 8, equirect_width: int | None = None,
         integrator: str = "direct", max_depth: int | None = None):
    """The Mitsuba scene of :func:`to_mitsuba` (its files removed once loaded)."""
    mi = _mi()
    with tempfile.TemporaryDirectory(prefix="viscache_mitsuba_") as folder:
        return mi.load_dict(to_mitsuba(setup, camera, envmap, spp, equirect_width, folder,
                                       integrator=integrator, max_depth=max_depth))


def from_mitsuba(source, envmap_resolution: int = 256, sphere_subdivisions: int = 4):
    """A :class:`~viscache_rs.Setup` read from a Mitsuba 3 scene: ``source`` is the path
    of an XML scene file or a ``mitsuba.load_dict`` dict (what :func:`to_mitsuba`
    returns). Mitsuba's own loader reads it in the ``scalar_rgb`` variant (no LLVM needed;
    the caller's variant is restored afterwards), so its includes, defaults, transforms
    and mesh formats mean what they mean to Mitsuba.

    What is read, each with an exact counterpart here:

    - shapes ``obj``, ``ply``, ``serialized``, ``cube`` and ``rectangle`` as their world-space
      triangles (``to_world`` applied); ``sphere`` as an icosphere of
      ``sphere_subdivisions`` (4: 5,120 triangles) under its ``to_world``; one object per
      shape, named by its id;
    - BSDFs ``diffuse`` (Lambert) and ``twosided`` around it or around ``viscache_phong``
      (normalised Phong) with a constant reflectance; ours shade the side facing the
      viewer, so a one-sided ``diffuse`` reads as Lambert too (they differ only seen from
      behind, where Mitsuba's is black);
    - ``area`` emitters with a constant radiance (one-sided, on the winding normal's side,
      as ours);
    - ``envmap`` and ``constant`` emitters, summed into one octahedral map of
      ``envmap_resolution``: each texel the mean of 16 evaluations of Mitsuba's own
      emitter (its ``to_world`` and ``scale`` included; about 3 s at 256², 0.2 s at 64²);
    - the first sensor, ``perspective``: its ``to_world`` (rotation and translation only),
      film size and field of view, whichever axis it was given on.

    Anything else (another shape, BSDF, emitter or sensor; a textured reflectance or
    radiance; a ``twosided`` with two different sides; a shifted principal point, a crop
    window or a mirrored camera; no sensor) raises ValueError naming the file or dict, the
    plugin and its id; an XML or plugin error Mitsuba raises is passed on as ValueError
    naming the file; a missing file raises FileNotFoundError.

    ``from_mitsuba(to_mitsuba(setup))`` gives the setup back: the same triangles, materials,
    area lights and camera rays, and the map to within the lat-long export's resolution."""
    from ._mitsuba_import import read

    return read(source, envmap_resolution=envmap_resolution,
                sphere_subdivisions=sphere_subdivisions)


def render(mi_scene, spp: int, seed: int = 0) -> np.ndarray:
    """Renders a loaded Mitsuba scene with ``spp`` samples per pixel, (H, W, 3) float64."""
    mi = _mi()
    return np.array(mi.render(mi_scene, spp=int(spp), seed=int(seed)), dtype=np.float64)
