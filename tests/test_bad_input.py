"""Bad input gets a ValueError or TypeError that names the argument, and changes nothing."""

import numpy as np
import pytest
import viscache_rs as vc
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32)
F = np.array([[0, 1, 2]])
ORIG = np.array([[0.2, 0.2, 1.0]], dtype=np.float32)
DIRS = np.array([[0.0, 0.0, -1.0]], dtype=np.float32)


@pytest.fixture
def scene():
    s = vc.Scene()
    s.add_mesh(V, F)
    return s


@pytest.mark.parametrize(
    "vertices, faces, exc, name",
    [
        (V[:, :2], F, ValueError, "vertices"),
        (V.ravel(), F, ValueError, "vertices"),
        (V.astype(bool), F, TypeError, "vertices"),
        (V.astype(complex), F, TypeError, "vertices"),
        (np.array([[0, np.nan, 0], [1, 0, 0], [0, 1, 0]]), F, ValueError, "vertices"),
        (np.array([[0, np.inf, 0], [1, 0, 0], [0, 1, 0]]), F, ValueError, "vertices"),
        (np.array([[0, 1e39, 0], [1, 0, 0], [0, 1, 0]]), F, ValueError, "vertices"),
        ("abc", F, TypeError, "vertices"),
        ([[0, 0], [1, 0, 0]], F, ValueError, "vertices"),
        (V, F.astype(np.float32), TypeError, "faces"),
        (V, np.array([[0, 1, 3]]), ValueError, "faces"),
        (V, np.array([[0, -1, 2]]), ValueError, "faces"),
        (V, np.array([[0, 1]]), ValueError, "faces"),
        (V, np.array([[0, 1, 2**40]], dtype=np.uint64), ValueError, "faces"),
    ],
)
def test_add_mesh_rejects(scene, vertices, faces, exc, name):
    before = scene.triangles()
    with pytest.raises(exc, match=f"^{name}"):
        scene.add_mesh(vertices, faces)
    assert scene.num_objects == 1
    np.testing.assert_array_equal(scene.triangles(), before)


def test_add_mesh_rejects_wrong_material_and_name(scene):
    with pytest.raises(TypeError):
        scene.add_mesh(V, F, material="red")
    with pytest.raises(TypeError):
        scene.add_mesh(V, F, name=5)
    assert scene.num_objects == 1


@pytest.mark.parametrize(
    "origins, directions, kwargs, exc, name",
    [
        (ORIG[:, :2], DIRS, {}, ValueError, "origins"),
        (ORIG, DIRS[:, :2], {}, ValueError, "directions"),
        (ORIG, np.zeros((1, 3)), {}, ValueError, "directions"),
        (np.array([[np.nan, 0, 0]]), DIRS, {}, ValueError, "origins"),
        (ORIG, np.array([[np.inf, 0, 0]]), {}, ValueError, "directions"),
        (ORIG, np.vstack([DIRS, DIRS]), {}, ValueError, "directions"),
        (ORIG.astype(bool), DIRS, {}, TypeError, "origins"),
        (ORIG, DIRS, {"tmax": -1.0}, ValueError, "tmax"),
        (ORIG, DIRS, {"tmax": np.nan}, ValueError, "tmax"),
        (ORIG, DIRS, {"tmax": np.array([1.0, 2.0])}, ValueError, "tmax"),
        (ORIG, DIRS, {"tmax": "far"}, TypeError, "tmax"),
        (ORIG, DIRS, {"threads": 0}, ValueError, "threads"),
        (ORIG, DIRS, {"threads": -3}, ValueError, "threads"),
        (ORIG, DIRS, {"threads": 2**70}, ValueError, "threads"),
        (ORIG, DIRS, {"threads": 1.5}, TypeError, "threads"),
    ],
)
@pytest.mark.parametrize("query", ["occluded", "intersect"])
def test_queries_reject(scene, query, origins, directions, kwargs, exc, name):
    scene.reset_counters()
    with pytest.raises(exc, match=f"^{name}"):
        getattr(scene, query)(origins, directions, **kwargs)
    assert scene.counters()["rays"] == 0, "a rejected call traces nothing"


def test_other_arguments_are_checked(scene, cornell):
    with pytest.raises(ValueError, match="^seed"):
        scene.gbuffer(cornell.camera, seed=-1)
    with pytest.raises(TypeError):
        scene.gbuffer("camera")
    with pytest.raises(ValueError, match="^normals"):
        scene.offset_points(ORIG, np.vstack([DIRS, DIRS]))
    with pytest.raises(ValueError, match="^obj"):
        scene.material(7)
    with pytest.raises(ValueError, match="^name"):
        vc.scenes.load("atrium")
    with pytest.raises(ValueError, match="^detail"):
        vc.scenes.load("cornell", detail=0)
    with pytest.raises(ValueError, match="^detail"):
        vc.scenes.load("cornell", detail=float("nan"))
    with pytest.raises(ValueError, match="^seed"):
        vc.scenes.load("cornell", seed=-2)


DTYPES = st.sampled_from(
    [np.float16, np.float32, np.float64, np.int8, np.int32, np.int64, np.uint32, np.uint64,
     np.bool_, np.complex64]
)


def arrays():
    shapes = hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=5)
    return DTYPES.flatmap(lambda dt: hnp.arrays(dt, shapes, elements=hnp.from_dtype(np.dtype(dt))))


ANYTHING = st.one_of(
    arrays(),
    st.none(),
    st.text(max_size=3),
    st.lists(st.floats(allow_nan=True), max_size=4),
    st.lists(st.lists(st.integers(-5, 5), min_size=3, max_size=3), max_size=4),
    st.integers(-(2**70), 2**70),
    st.floats(allow_nan=True, allow_infinity=True),
)
ALLOWED = (ValueError, TypeError)


@settings(max_examples=300, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(vertices=ANYTHING, faces=ANYTHING)
def test_fuzz_add_mesh(vertices, faces):
    s = vc.Scene()
    try:
        s.add_mesh(vertices, faces)
    except ALLOWED:
        assert s.num_objects == 0
        return
    assert s.num_objects == 1


@settings(max_examples=300, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(origins=ANYTHING, directions=ANYTHING, tmax=ANYTHING, threads=st.one_of(st.none(), ANYTHING))
def test_fuzz_queries(origins, directions, tmax, threads):
    s = vc.Scene()
    s.add_mesh(V, F)
    for query in (s.occluded, s.intersect):
        try:
            out = query(origins, directions, tmax=tmax, threads=threads)
        except ALLOWED:
            continue
        n = np.asarray(origins).shape[0]
        assert len(out) == n if query == s.occluded else len(out["t"]) == n


NUMBERISH = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=3),
    st.lists(st.integers(-3, 3), max_size=3),
)


@pytest.fixture(scope="module")
def tiny():
    s = vc.scenes.load("cornell", detail=0.3)
    s.camera = s.camera.with_resolution(6, 4)
    return s


@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(spp=NUMBERISH, seed=NUMBERISH, threads=NUMBERISH, time_budget=NUMBERISH,
       product_level=NUMBERISH, size=st.tuples(NUMBERISH, NUMBERISH))
def test_fuzz_render_arguments(tiny, spp, seed, threads, time_budget, product_level, size):
    """Any value for the numeric arguments of a render and a camera size renders or raises
    ValueError/TypeError (MemoryError for sizes too large to allocate) naming the argument;
    nothing else escapes, nothing panics."""
    try:
        cam = tiny.camera.with_resolution(*size)
    except ALLOWED as e:
        assert str(e).split(":")[0] in ("width", "height"), e
        cam = tiny.camera
    names = ("spp", "seed", "threads", "time_budget", "product_level", "camera")
    if isinstance(spp, int) and spp > 8:
        spp = 8  # keep valid renders quick
    try:
        r = vc._core.render(tiny.scene, tiny.envmap, cam, spp, "product", seed=seed,
                            threads=threads, time_budget=time_budget,
                            product_level=product_level)
    except (*ALLOWED, MemoryError) as e:
        assert str(e).split(":")[0] in names, e
        return
    assert np.isfinite(r["image"]).all()


class _NotASetup:
    """Has a scene but a camera and map of the wrong types, as a hand-made setup might."""

    def __init__(self, setup):
        self.scene, self.camera, self.envmap = setup.scene, "cam", setup.envmap


def test_entry_points_name_a_setup_camera_map_or_cache_of_the_wrong_type(tiny):
    """``vc.render(S, camera="cam")`` and ``vc.render("setup")`` raised AttributeError deep
    inside the call; every entry point that takes a setup, camera, map or cache now raises
    TypeError naming the argument, before any work."""
    cache = vc.VisibilityCache(tiny.scene)
    calls = {
        "render": lambda **kw: vc.render(**{"setup": tiny, "spp": 1, "progress": False, **kw}),
        "render vpl": lambda **kw: vc.render(**{"setup": tiny, "spp": 1, "method": "vpl",
                                                "progress": False, **kw}),
        "render_ao": lambda **kw: vc.render_ao(**{"setup": tiny, "progress": False, **kw}),
        "preview": lambda **kw: vc.preview(**{"setup": tiny, "cache": cache, **kw}),
        "Relighter": lambda **kw: vc.Relighter(**{"setup": tiny, **kw}),
    }
    for name, call in calls.items():
        for kw, argument in (({"setup": "setup"}, "setup"), ({"setup": 3}, "setup"),
                             ({"setup": _NotASetup(tiny)}, "setup"),
                             ({"camera": "cam"}, "camera"), ({"camera": tiny}, "camera")):
            with pytest.raises(TypeError, match=f"^{argument}: expected "):
                call(**kw)
        if name not in ("render_ao", "Relighter"):
            with pytest.raises(TypeError, match="^envmap: expected an EnvMap"):
                call(envmap="sky")
    with pytest.raises(TypeError, match="^cache: expected a VisibilityCache"):
        vc.render(tiny, method="cv", cache="cache", progress=False)
    with pytest.raises(TypeError, match="^cache: expected a VisibilityCache"):
        vc.preview(tiny, "cache")
    with pytest.raises(TypeError, match="^cache: expected a VisibilityCache"):
        vc.render_ao(tiny, cache=tiny, progress=False)
    with pytest.raises(TypeError, match="^cache: expected a VisibilityCache"):
        vc.Relighter(tiny, visibility="cache", cache="cache")
    with pytest.raises(TypeError, match="^gbuffer: expected a GBuffer"):
        vc.render(tiny, gbuffer="g", progress=False)
    # A setup of the right types renders, hand-made or built in.
    own = vc.Setup(tiny.scene, tiny.camera, tiny.envmap)
    assert vc.render(own, spp=1, progress=False).image.shape == (4, 6, 3)
