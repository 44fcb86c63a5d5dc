"""Runtime signatures of the native module state their defaults, and None passed explicitly
still means the default (wrappers forward their own None)."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import numpy as np
import pytest
import viscache_rs as vc
from viscache_rs import _core


def _defaults(f) -> dict[str, object]:
    return {k: p.default for k, p in inspect.signature(f).parameters.items()
            if p.default is not inspect.Parameter.empty}


def test_signatures_show_the_numbers_they_default_to():
    assert _defaults(_core.Camera.look_at) == {
        "up": (0, 1, 0), "fov_deg": 45.0, "width": 256, "height": 192}
    assert _defaults(_core.EnvMap.constant) == {"resolution": 256}
    assert _defaults(_core.load_scene) == {"detail": 1.0, "seed": 0, "animated": False,
                                            "variant": None}
    assert _defaults(_core.render)["seed"] == 0
    assert _defaults(_core.render)["alpha_radius"] == 4
    assert _defaults(_core.VisibilityCache.validate) == {
        "rays_per_record": 16, "seed": 0, "threads": None}
    assert _defaults(_core.analysis.sample_pairs)["neighbours"] == 16
    assert _defaults(_core.testing.chi2_sphere) == {
        "resolution": 32, "subdivisions": 8, "min_expected": 5.0, "significance": 0.01}


def test_an_explicit_none_means_the_default():
    eye, target = (0, 1, 5), (0, 0, 0)
    a = vc.Camera.look_at(eye, target)
    b = vc.Camera.look_at(eye, target, up=None, fov_deg=None, width=None, height=None)
    assert (a.width, a.height, a.fov_deg, a.up) == (b.width, b.height, b.fov_deg, b.up)
    small = a.with_resolution(4, 3)
    for x, y in zip(small.rays(), small.rays(seed=None), strict=True):
        np.testing.assert_array_equal(x, y)
    assert vc.EnvMap.constant(1.0, resolution=None).resolution == 256
    m = vc.Material.lambert((0.5, 0.5, 0.5))
    np.testing.assert_array_equal(m.product_cells((0, 1, 0), (0, 1, 0), level=None),
                                  m.product_cells((0, 1, 0), (0, 1, 0), level=5))


# stubtest checks the module's own names; the native submodules are typed in _core.pyi as
# namespace classes, which it does not compare. This does, by name and default.
_SUBMODULE_STUBS = {
    "_OctahedralModule": _core.octahedral,
    "_TestingModule": _core.testing,
    "_AnalysisModule": _core.analysis,
    "_VisibilityMaps": _core.analysis.VisibilityMaps,
}


def _stub_classes() -> dict[str, ast.ClassDef]:
    path = Path(_core.__file__).with_name("_core.pyi")
    if not path.is_file():
        pytest.skip("the stubs are not installed beside the module")
    tree = ast.parse(path.read_text())
    return {n.name: n for n in tree.body if isinstance(n, ast.ClassDef)}


def _stub_parameters(f: ast.FunctionDef) -> list[tuple[str, object]]:
    args = f.args.args
    defaults = [inspect.Parameter.empty] * (len(args) - len(f.args.defaults)) + [
        ast.literal_eval(d) if not isinstance(d, ast.Constant) or d.value is not ... else ...
        for d in f.args.defaults]
    out = [(a.arg, d) for a, d in zip(args, defaults, strict=True)]
    return [p for p in out if p[0] != "self"]


def test_submodule_stubs_match_the_runtime():
    classes = _stub_classes()
    for stub_name, runtime in _SUBMODULE_STUBS.items():
        stub = classes[stub_name]
        funcs = {f.name: f for f in stub.body if isinstance(f, ast.FunctionDef)}
        public = {n for n in dir(runtime) if not n.startswith("_")
                  and callable(getattr(runtime, n)) and not isinstance(getattr(runtime, n), type)}
        assert public <= set(funcs), f"{stub_name}: not in the stub: {public - set(funcs)}"
        for name in public:
            sig = inspect.signature(getattr(runtime, name))
            have = [(k, p.default) for k, p in sig.parameters.items() if k != "self"]
            assert have == _stub_parameters(funcs[name]), f"{stub_name}.{name}"
