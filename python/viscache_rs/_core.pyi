"""Typed stubs of the native module viscache_rs._core."""

from collections.abc import Callable, Iterator
from os import PathLike
from pathlib import Path
from typing import Any, Self, final

import numpy as np
import numpy.typing as npt
from typing_extensions import disjoint_base

__all__ = [
    "__version__",
    "Scene",
    "Camera",
    "Material",
    "Setup",
    "EnvMap",
    "GBuffer",
    "ImportanceCache",
    "IrradianceCache",
    "ProxyGrid",
    "Proxies",
    "VisibilityCache",
    "LightingPreview",
    "Relighter",
    "render",
    "methods",
    "check_method_args",
    "own_cache_record_cap",
    "DEFAULT_VPLS",
    "DEFAULT_VPL_SAMPLES",
    "OWN_CACHE_SAMPLES_PER_RECORD",
    "OWN_CACHE_BUDGET_SHARE",
    "LIMITS",
    "VPLs",
    "render_ao",
    "write_exr",
    "scene_names",
    "load_scene",
    "animated_scene_names",
    "scene_variants",
    "indirect_scene_names",
    "testing",
    "octahedral",
    "analysis",
]

__version__: str

_ArrayLike = npt.ArrayLike

@final
class Material:
    @staticmethod
    def lambert(albedo: _ArrayLike) -> Material: ...
    @staticmethod
    def phong(kd: _ArrayLike, ks: _ArrayLike, exponent: float) -> Material: ...
    @property
    def kind(self) -> str: ...
    def params(self) -> dict[str, Any]: ...
    def eval(
        self, normals: _ArrayLike, wo: _ArrayLike, wi: _ArrayLike
    ) -> npt.NDArray[np.float32]: ...
    def sample(
        self, normals: _ArrayLike, wo: _ArrayLike, u: _ArrayLike
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]]: ...
    def pdf(
        self, normals: _ArrayLike, wo: _ArrayLike, wi: _ArrayLike
    ) -> npt.NDArray[np.float64]: ...
    def product_cells(
        self, normal: _ArrayLike, wo: _ArrayLike, level: int | None = 5
    ) -> npt.NDArray[np.float32]: ...

@final
class Camera:
    @staticmethod
    def look_at(
        eye: _ArrayLike,
        target: _ArrayLike,
        up: _ArrayLike | None = (0, 1, 0),
        fov_deg: float | None = 45.0,
        width: int | None = 256,
        height: int | None = 192,
    ) -> Camera: ...
    def with_resolution(self, width: int, height: int) -> Camera: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def fov_deg(self) -> float: ...
    @property
    def eye(self) -> tuple[float, float, float]: ...
    @property
    def forward(self) -> tuple[float, float, float]: ...
    @property
    def right(self) -> tuple[float, float, float]: ...
    @property
    def up(self) -> tuple[float, float, float]: ...
    def rays(
        self, seed: int | None = 0, jitter: bool = True
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]: ...

@final
class Scene:
    def __init__(self) -> None: ...
    def add_mesh(
        self,
        vertices: _ArrayLike,
        faces: _ArrayLike,
        material: Material | None = None,
        name: str | None = None,
    ) -> int: ...
    @staticmethod
    def from_obj(path: str | PathLike[str]) -> Scene: ...
    @staticmethod
    def from_trimesh(mesh: Any) -> Scene: ...
    @staticmethod
    def load(path: str | PathLike[str]) -> Scene: ...
    @property
    def num_triangles(self) -> int: ...
    @property
    def num_objects(self) -> int: ...
    @property
    def bounds(self) -> npt.NDArray[np.float32]: ...
    def triangles(self) -> npt.NDArray[np.float32]: ...
    def object_ids(self) -> npt.NDArray[np.int32]: ...
    def object_names(self) -> list[str]: ...
    def material(self, obj: int) -> Material: ...
    def set_material(self, obj: int, material: Material) -> None: ...
    def build(self, quality: str = "auto", threads: int | None = None) -> float: ...
    def bvh_stats(self) -> dict[str, Any]: ...
    def occluded(
        self,
        origins: _ArrayLike,
        directions: _ArrayLike,
        tmax: float | _ArrayLike | None = None,
        threads: int | None = None,
    ) -> npt.NDArray[np.bool_]: ...
    def intersect(
        self,
        origins: _ArrayLike,
        directions: _ArrayLike,
        tmax: float | _ArrayLike | None = None,
        threads: int | None = None,
    ) -> dict[str, npt.NDArray[Any]]: ...
    def offset_points(self, points: _ArrayLike, normals: _ArrayLike) -> npt.NDArray[np.float32]: ...
    def add_area_light(
        self, vertices: _ArrayLike, radiance: _ArrayLike, name: str | None = None
    ) -> int: ...
    def set_emitter(self, obj: int, radiance: _ArrayLike) -> None: ...
    def set_emission(self, obj: int, radiance: _ArrayLike) -> None: ...
    def set_emission_texture(self, obj: int, texture: _ArrayLike | None) -> None: ...
    def area_lights(self) -> list[int]: ...
    def emission(self, obj: int) -> tuple[float, float, float]: ...
    def counters(self) -> dict[str, int]: ...
    def reset_counters(self) -> None: ...
    counting: bool
    def gbuffer(
        self,
        camera: Camera,
        seed: int | None = 0,
        jitter: bool = True,
        threads: int | None = None,
    ) -> GBuffer: ...
    def __len__(self) -> int: ...

@final
class GBuffer:
    @property
    def camera(self) -> Camera: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def jittered(self) -> bool: ...
    @property
    def seed(self) -> int: ...
    @property
    def covered_pixels(self) -> int: ...
    def keys(self) -> list[str]: ...
    def as_dict(self) -> dict[str, npt.NDArray[Any]]: ...
    def __getitem__(self, key: str, /) -> npt.NDArray[Any]: ...
    def __contains__(self, key: str, /) -> bool: ...
    def __iter__(self) -> Iterator[str]: ...
    # Attached in Python (viscache_rs.display).
    def _repr_png_(self) -> bytes: ...
    def save(self, path: str | PathLike[str], key: str = "normal") -> Path: ...

@final
class EnvMap:
    @staticmethod
    def from_equirect(rgb: _ArrayLike, resolution: int = 256) -> EnvMap: ...
    @staticmethod
    def from_octahedral(rgb: _ArrayLike) -> EnvMap: ...
    @staticmethod
    def from_exr(path: str | PathLike[str], resolution: int | None = None) -> EnvMap: ...
    @staticmethod
    def constant(value: float | _ArrayLike, resolution: int = 256) -> EnvMap: ...
    @staticmethod
    def sky(
        sun_dir: _ArrayLike,
        sun_radiance: float | _ArrayLike,
        sun_angle: float,
        zenith: float | _ArrayLike,
        horizon: float | _ArrayLike,
        resolution: int = 256,
    ) -> EnvMap: ...
    @staticmethod
    def windows(
        windows: list[Any], background: float | _ArrayLike, resolution: int = 256
    ) -> EnvMap: ...
    def to_exr(self, path: str | PathLike[str], layout: str = "octahedral") -> None: ...
    def to_equirect(self, width: int, height: int) -> npt.NDArray[np.float32]: ...
    def rotated(self, degrees: float) -> EnvMap: ...
    @property
    def resolution(self) -> int: ...
    @property
    def is_black(self) -> bool: ...
    def texels(self) -> npt.NDArray[np.float32]: ...
    def eval(self, dirs: _ArrayLike) -> npt.NDArray[np.float32]: ...
    def pdf(self, dirs: _ArrayLike) -> npt.NDArray[np.float64]: ...
    def sample(
        self, u: _ArrayLike
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float64]]: ...
    def invert(self, dirs: _ArrayLike) -> npt.NDArray[np.float64]: ...
    def total_power(self) -> tuple[float, float, float]: ...
    # Attached in Python (viscache_rs.display).
    def _repr_png_(self) -> bytes: ...
    def save(self, path: str | PathLike[str], exposure: float | None = None) -> Path: ...

@final
class Setup:
    def __new__(
        cls, scene: Scene, camera: Camera, envmap: EnvMap, name: str | None = None
    ) -> Setup: ...
    @property
    def name(self) -> str: ...
    scene: Scene
    camera: Camera
    envmap: EnvMap
    def at_frame(self, frame: int) -> None: ...
    @property
    def frame(self) -> int: ...
    @property
    def variant(self) -> str | None: ...
    @property
    def animated(self) -> bool: ...
    @property
    def moving_object(self) -> int | None: ...
    @property
    def period(self) -> int | None: ...
    def moving_bounds(self) -> npt.NDArray[np.float32] | None: ...
    @staticmethod
    def load(path: str | PathLike[str]) -> Setup: ...
    def save(self, path: str | PathLike[str]) -> None: ...

@disjoint_base
class ProxyGrid:
    """VF's proxies, their VPLs and voxel grids. Subclassed by ``viscache_rs.vf.ProxyGrid``,
    which takes a setup."""

    def __new__(
        cls,
        scene: Scene,
        envmap: EnvMap,
        proxies: int | None = None,
        voxels: int | tuple[int, int, int] | None = None,
        seed: int | None = 0,
        threads: int | None = None,
        table_slots: int | None = None,
    ) -> Self: ...
    @property
    def scene(self) -> Scene: ...
    @property
    def envmap(self) -> EnvMap: ...
    @property
    def seed(self) -> int: ...
    @property
    def voxels(self) -> tuple[int, int, int]: ...
    @property
    def stats(self) -> dict[str, Any]: ...
    def __len__(self) -> int: ...

@final
class Proxies:
    """BLD's geometry proxies for ``render(method="stochastic", proxies=...)``: cheap
    triangles standing for some of a scene's objects with one guarantee (``kind``):
    "outside" (encloses each object; solid), "inside" (within each watertight object) or
    "general". Their own scene and BVH, tied to the scene they were made for."""

    @staticmethod
    def boxes(scene: Scene, objects: list[int] | None = None) -> Proxies: ...
    @staticmethod
    def from_meshes(
        scene: Scene,
        meshes: dict[int, tuple[npt.ArrayLike, npt.ArrayLike]],
        kind: str = "outside",
    ) -> Proxies: ...
    @staticmethod
    def build(
        scene: Scene,
        kind: str = "outside",
        hull: bool = False,
        target: int | None = None,
        spheres: int | None = None,
        cell: float | None = None,
        objects: list[int] | None = None,
    ) -> Proxies: ...
    @property
    def kind(self) -> str: ...
    @property
    def num_triangles(self) -> int: ...
    @property
    def objects(self) -> list[int]: ...

@disjoint_base
class ImportanceCache:
    """Importance records over a scene and a light set (survey ch. 6). Subclassed by
    ``viscache_rs.ImportanceCache``, which adds the progress bar to ``build``."""

    def __new__(
        cls,
        scene: Scene,
        lights: VPLs,
        spacing: int | None = None,
        nearest: int | None = None,
        lam: float | None = None,
        alpha: tuple[float, float, float, float] | None = None,
    ) -> ImportanceCache: ...
    @property
    def scene(self) -> Scene: ...
    @property
    def lights(self) -> VPLs: ...
    @property
    def params(self) -> dict[str, Any]: ...
    def memory_bytes(self) -> int: ...
    def __len__(self) -> int: ...
    def build(
        self,
        camera: Camera | None = None,
        seed: int | None = 0,
        threads: int | None = None,
        *,
        gbuffer: GBuffer | None = None,
        time_budget: float | None = None,
        callback: Any = None,
    ) -> dict[str, Any]: ...
    def lookup(
        self, points: _ArrayLike, normals: _ArrayLike, lam: float | None = None
    ) -> dict[str, npt.NDArray[Any]]: ...
    def records(self) -> dict[str, npt.NDArray[Any]]: ...
    def save(self, path: str | PathLike[str]) -> None: ...
    @classmethod
    def load(
        cls, path: str | PathLike[str], scene: Scene, lights: VPLs
    ) -> ImportanceCache: ...

@disjoint_base
class IrradianceCache:
    """One-bounce irradiance records with gradients (survey ch. 3). Subclassed by
    ``viscache_rs.IrradianceCache``, which adds the progress bar to ``build``."""

    def __new__(
        cls,
        scene: Scene,
        a: float | None = None,
        strata: tuple[int, int] | None = None,
        r_min: float | None = None,
        r_max: float | None = None,
        gradients: str | None = None,
        clamp_neighbours: bool | None = None,
        secondary_spp: int | None = None,
    ) -> IrradianceCache: ...
    @property
    def scene(self) -> Scene: ...
    @property
    def params(self) -> dict[str, Any]: ...
    @property
    def record_bytes(self) -> int: ...
    def memory_bytes(self) -> int: ...
    def __len__(self) -> int: ...
    def build(
        self,
        camera: Camera | None = None,
        seed: int | None = 0,
        threads: int | None = None,
        *,
        envmap: EnvMap,
        gbuffer: GBuffer | None = None,
        time_budget: float | None = None,
        callback: Any = None,
    ) -> dict[str, Any]: ...
    def insert(
        self,
        point: _ArrayLike,
        normal: _ArrayLike,
        *,
        envmap: EnvMap,
        footprint: float | None = None,
        seed: int | None = 0,
    ) -> int: ...
    def lookup(
        self, points: _ArrayLike, normals: _ArrayLike, threads: int | None = None
    ) -> dict[str, Any]: ...
    def records(self) -> dict[str, npt.NDArray[np.float32]]: ...
    def stats(self) -> dict[str, int]: ...
    def save(self, path: str | PathLike[str]) -> None: ...
    @classmethod
    def load(cls, path: str | PathLike[str], scene: Scene) -> Self: ...

@disjoint_base
class VisibilityCache:
    """World-space visibility records over a scene (CAM08 sec. 5). Subclassed by
    ``viscache_rs.VisibilityCache``, which adds the progress bar to ``build``."""

    def __new__(
        cls,
        scene: Scene,
        resolution: int | None = None,
        preset: str = "auto",
        **overrides: Any,
    ) -> VisibilityCache: ...
    @property
    def scene(self) -> Scene: ...
    @property
    def resolution(self) -> int: ...
    @property
    def params(self) -> dict[str, Any]: ...
    @property
    def frame(self) -> int: ...
    @property
    def default_radius(self) -> float | None: ...
    def __len__(self) -> int: ...
    def bind(self, scene: Scene) -> None: ...
    def directions(self) -> npt.NDArray[np.float32]: ...
    def build(
        self,
        camera: Camera | None = None,
        seed: int | None = 0,
        threads: int | None = None,
        *,
        gbuffer: GBuffer | None = None,
        time_budget: float | None = None,
        callback: Callable[[int, int], Any] | None = None,
        spp: int | None = None,
    ) -> dict[str, Any]: ...
    def insert(self, point: _ArrayLike, normal: _ArrayLike) -> int | None: ...
    def lookup(
        self,
        points: _ArrayLike,
        normals: _ArrayLike,
        radius: float | _ArrayLike | None = None,
        footprints: _ArrayLike | None = None,
        interpolate: bool = False,
        threads: int | None = None,
    ) -> dict[str, npt.NDArray[Any]]: ...
    def record_bits(self, id: int) -> npt.NDArray[np.bool_]: ...
    def record_hierarchy(self, id: int) -> list[npt.NDArray[np.uint8]]: ...
    def memory_bytes(self) -> int: ...
    def records(self) -> dict[str, npt.NDArray[Any]]: ...
    def record_misses(self, ids: _ArrayLike, misses: _ArrayLike, uses: _ArrayLike) -> None: ...
    def validate(
        self, rays_per_record: int | None = 16, seed: int | None = 0, threads: int | None = None
    ) -> dict[str, int]: ...
    def end_frame(self) -> dict[str, int]: ...
    def stats(self) -> dict[str, Any]: ...
    def save(self, path: str | PathLike[str]) -> None: ...
    @classmethod
    def load(cls, path: str | PathLike[str], scene: Scene) -> Self: ...

@final
class LightingPreview:
    def __new__(
        cls,
        scene: Scene,
        camera: Camera | None = None,
        threads: int | None = None,
        gbuffer: GBuffer | None = None,
    ) -> LightingPreview: ...
    @property
    def size(self) -> tuple[int, int]: ...
    def render(
        self,
        cache: VisibilityCache,
        envmap: EnvMap,
        rotation: float | _ArrayLike | None = None,
        product_level: int | str | None = None,
        threads: int | None = None,
        direct: bool = False,
    ) -> npt.NDArray[np.float32]: ...
    def prepare(
        self,
        cache: VisibilityCache,
        envmap: EnvMap | None = None,
        basis: str = "auto",
        budget_mb: float | None = None,
        product_level: int | str | None = None,
        nearest: bool | None = None,
        edge_rays: float | None = None,
        threads: int | None = None,
    ) -> dict[str, Any]: ...
    @property
    def transfer_info(self) -> dict[str, Any] | None: ...
    @property
    def last_bright(self) -> dict[str, Any] | None: ...
    def set_material(
        self,
        obj: int,
        material: Material,
        cache: VisibilityCache | None = None,
        threads: int | None = None,
    ) -> int: ...

@final
class Relighter:
    def __new__(
        cls, scene: Scene, gbuffer: GBuffer, visibility: str = "pixels"
    ) -> Relighter: ...
    @property
    def visibility(self) -> str: ...
    @property
    def visibility_spp(self) -> int: ...
    def converge_visibility(
        self,
        envmap: EnvMap,
        spp: int,
        seed: int | None = 0,
        product_level: int | str | None = None,
        threads: int | None = None,
        time_budget: float | None = None,
        callback: Callable[[int, int], Any] | None = None,
    ) -> dict[str, Any]: ...
    def render(
        self,
        envmap: EnvMap,
        materials: dict[int, Material] | None = None,
        cache: VisibilityCache | None = None,
        light_cache: VisibilityCache | None = None,
        lb_spp: int | None = 64,
        lbv_spp: int | None = 8,
        threshold: float | None = 0.25,
        epsilon: float | None = 0.1,
        seed: int | None = 0,
        product_level: int | str | None = None,
        threads: int | None = None,
        time_budget: float | None = None,
        adaptive: bool = True,
        least_error: bool = True,
        reuse: bool = True,
        callback: Callable[[int, int], Any] | None = None,
    ) -> dict[str, Any]: ...

def write_exr(path: str | PathLike[str], image: _ArrayLike) -> None: ...
def render(
    scene: Scene,
    envmap: EnvMap,
    camera: Camera,
    spp: int | None = None,
    method: str = "mis",
    seed: int | None = 0,
    threads: int | None = None,
    time_budget: float | None = None,
    product_level: int | str | None = None,
    callback: Any = None,
    cache: VisibilityCache | IrradianceCache | ImportanceCache | None = None,
    jitter: bool = True,
    alpha: float | str | tuple[float, float, float, float] | None = None,
    alpha_radius: int | None = 4,
    insert_missing: bool = False,
    technique_weights: dict[str, float] | None = None,
    bounces: int | None = None,
    direct: bool = True,
    gbuffer: GBuffer | None = None,
    light_samples: int | None = None,
    learn_techniques: bool = True,
    adaptive: bool | None = None,
    preset: str = "auto",
    vpls: VPLs | None = None,
    clamp: float | None = None,
    vpl_samples: int | None = None,
    a: float | None = None,
    strata: tuple[int, int] | None = None,
    r_min: float | None = None,
    r_max: float | None = None,
    gradients: str | None = None,
    clamp_neighbours: bool | None = None,
    secondary_spp: int | None = None,
    proxies: int | ProxyGrid | Proxies | None = None,
    voxels: int | tuple[int, int, int] | None = None,
    marching: int | tuple[int, int] | None = None,
    indirect: int | tuple[int, int] | None = None,
    rays_per_pixel: int | None = None,
    filter: int | None = None,
    depth_tol: float | None = None,
    normal_tol: float | None = None,
    sh_range: float | None = None,
    sampling: str | None = None,
    combine: str | None = None,
    lam: float | None = None,
    spacing: int | None = None,
    nearest: int | None = None,
    probabilities: str | None = None,
    probe_rays: int | None = None,
) -> dict[str, Any]: ...
def methods() -> list[dict[str, Any]]: ...
def own_cache_record_cap(pixels: int, spp: int, preset: str = "auto") -> int: ...

DEFAULT_VPLS: int
DEFAULT_VPL_SAMPLES: int
OWN_CACHE_SAMPLES_PER_RECORD: int
OWN_CACHE_BUDGET_SHARE: float
#: name -> (low, high) of the core's own checks: spp, threads, seed, detail (low excluded),
#: image_side (camera width and height), record_resolution (powers of two), alpha.
LIMITS: dict[str, tuple[Any, Any]]

def check_method_args(
    method: str,
    given: list[str],
    cache: VisibilityCache | IrradianceCache | ImportanceCache | None = None,
) -> None: ...
@final
class VPLs:
    """Virtual point lights (``viscache_rs.vpl``)."""

    @staticmethod
    def trace(
        setup: Any,
        count: int,
        seed: int | None = 0,
        importance: bool = True,
        depth: int | None = 1,
        epsilon: float | None = 0.05,
        pilot_paths: int | None = 4000,
        lights: bool = True,
        camera: Camera | None = None,
        envmap: EnvMap | None = None,
        threads: int | None = None,
    ) -> VPLs: ...
    @staticmethod
    def from_lights(
        scene: Scene, positions: _ArrayLike, normals: _ArrayLike, flux: _ArrayLike
    ) -> VPLs: ...
    @staticmethod
    def from_surface(
        scene: Scene,
        positions: _ArrayLike,
        normals: _ArrayLike,
        irradiance: _ArrayLike,
        areas: _ArrayLike,
        objects: _ArrayLike,
    ) -> VPLs: ...
    @staticmethod
    def from_envmap(
        env_or_setup: EnvMap | Any, level: int = 4, scene: Scene | None = None
    ) -> VPLs: ...
    @staticmethod
    def from_directions(scene: Scene, directions: _ArrayLike, irradiance: _ArrayLike) -> VPLs: ...
    @staticmethod
    def from_area_lights(scene: Scene, points: int = 16) -> VPLs: ...
    def view_share(
        self,
        setup: Any,
        camera: Camera | None = None,
        width: int = 64,
        threads: int | None = None,
    ) -> dict[str, Any]: ...
    def __add__(self, other: VPLs, /) -> VPLs: ...
    def __radd__(self, other: VPLs, /) -> VPLs: ...
    def __len__(self) -> int: ...
    @property
    def positions(self) -> npt.NDArray[np.float32]: ...
    @property
    def normals(self) -> npt.NDArray[np.float32]: ...
    @property
    def flux(self) -> npt.NDArray[np.float32]: ...
    @property
    def incident(self) -> npt.NDArray[np.float32]: ...
    @property
    def area_points(self) -> npt.NDArray[np.int32]: ...
    @property
    def bounces(self) -> npt.NDArray[np.int32]: ...
    @property
    def kinds(self) -> npt.NDArray[np.int8]: ...
    @property
    def disk_area(self) -> float: ...
    @property
    def stats(self) -> dict[str, Any]: ...

def render_ao(
    scene: Scene,
    camera: Camera | None = None,
    cache: VisibilityCache | None = None,
    reference_rays: int | None = None,
    seed: int | None = 0,
    threads: int | None = None,
    time_budget: float | None = None,
    sigma_scale: float | None = None,
    min_radius_scale: float | None = None,
    w_min: float | None = None,
    callback: Any = None,
    gbuffer: GBuffer | None = None,
) -> dict[str, Any]: ...
def scene_names() -> list[str]: ...
def load_scene(
    name: str,
    detail: float | None = 1.0,
    seed: int | None = 0,
    animated: bool = False,
    variant: str | None = None,
) -> Setup: ...
def animated_scene_names() -> list[str]: ...
def scene_variants(name: str) -> list[str]: ...
def indirect_scene_names() -> list[tuple[str, str | None]]: ...

# Submodules of the native module, typed as namespaces (stubtest does not compare these;
# tests/test_signatures.py does).
class _OctahedralModule:
    @staticmethod
    def sphere_to_square(dirs: _ArrayLike) -> npt.NDArray[np.float32]: ...
    @staticmethod
    def square_to_sphere(uv: _ArrayLike) -> npt.NDArray[np.float32]: ...
    @staticmethod
    def texel_of(dirs: _ArrayLike, res: int) -> npt.NDArray[np.int64]: ...

class _TestingModule:
    @staticmethod
    def simd_level() -> str: ...
    @staticmethod
    def ground_hemisphere_rays(
        scene: Scene, n: int, seed: int | None = 0
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]: ...
    @staticmethod
    def record_bundle_rays(
        scene: Scene, points: int, side: int | None = 32, seed: int | None = 0
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]: ...

    @staticmethod
    def chi2_sphere(
        dirs: _ArrayLike,
        pdf: Any,
        resolution: int | None = 32,
        subdivisions: int | None = 8,
        min_expected: float | None = 5.0,
        significance: float | None = 0.01,
    ) -> dict[str, Any]: ...

class _VisibilityMaps:
    """Visibility maps of many surface points (CAM08 eq. 7), from analysis.visibility_maps."""

    def __len__(self) -> int: ...
    @property
    def resolution(self) -> int: ...
    @property
    def points(self) -> npt.NDArray[np.float32]: ...
    @property
    def normals(self) -> npt.NDArray[np.float32]: ...
    def visible_fraction(self) -> npt.NDArray[np.float64]: ...
    def bits(self, indices: _ArrayLike | None = None) -> npt.NDArray[np.bool_]: ...

class _AnalysisModule:
    VisibilityMaps: type[_VisibilityMaps]
    @staticmethod
    def visibility_maps(
        scene: Scene,
        points: _ArrayLike,
        normals: _ArrayLike,
        resolution: int | None = 32,
        threads: int | None = None,
        callback: Callable[[int, int], Any] | None = None,
    ) -> _VisibilityMaps: ...
    @staticmethod
    def sample_pairs(
        maps: _VisibilityMaps,
        neighbours: int | None = 16,
        far: int | None = 16,
        far_range: _ArrayLike | None = None,
        seed: int | None = 0,
        threads: int | None = None,
    ) -> npt.NDArray[np.uint32]: ...
    @staticmethod
    def pair_correlations(maps: _VisibilityMaps, pairs: _ArrayLike) -> dict[str, Any]: ...
    @staticmethod
    def correlation_bins(
        maps: _VisibilityMaps,
        distance_edges: _ArrayLike,
        theta_edges: _ArrayLike,
        pairs: _ArrayLike | None = None,
        threads: int | None = None,
    ) -> dict[str, Any]: ...
    @staticmethod
    def local_correlation(
        maps: _VisibilityMaps, d_max: float, theta_max_deg: float, threads: int | None = None
    ) -> dict[str, Any]: ...

octahedral: _OctahedralModule
testing: _TestingModule
analysis: _AnalysisModule
