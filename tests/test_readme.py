"""Every Python block of README.md runs as written, so that the README cannot drift from the
library.

Each ```` ```python ```` block runs on its own (a fresh namespace, in an empty temporary
folder), at a small size so that all of them take seconds: the built-in setups' cameras are
shrunk to ``SMALL`` pixels and their maps to ``SMALL_MAP``² texels (``vc.scenes.load`` is
wrapped), and the text of the block goes through the substitutions of ``SHRINK`` (sample
counts, reference rays, VPL counts, time budgets, explicit camera sizes and the width of
Mitsuba's copy of the map) before it runs. Nothing else is changed: a name the block does
not define, a key a result lacks or a wrong argument fails the test as it would fail a
reader. A block that imports a module which is not installed (``trimesh``; ``mitsuba``
without the test extra) is skipped.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest
import viscache_rs as vc

README = Path(__file__).resolve().parents[1] / "README.md"

#: The size every built-in setup's camera is shrunk to.
SMALL = (32, 24)
#: The resolution its map is shrunk to (the lighting preview's preparation and the product
#: distributions cost in proportion to the map's texels).
SMALL_MAP = 64

#: (pattern, replacement) applied to a block's text in order: the knobs of size.
SHRINK = [
    (r"\bspp=(\d[\d_]*)", r"spp=min(\1, 2)"),
    (r"\b(lb|lbv)_spp=\d+", r"\1_spp=2"),
    (r"\bvpl_samples=\d+", "vpl_samples=2"),
    (r"\breference_rays=\d+", "reference_rays=8"),
    (r"\bcount=[\d_]+", "count=200"),
    (r"\btime_budget=\d+(\.\d*)?", "time_budget=0.1"),
    (r"\bwidth=\d+, height=\d+", f"width={SMALL[0]}, height={SMALL[1]}"),
    # Mitsuba's copy of the map: its default width (16 pixels per texel) takes most of a
    # minute to build.
    (r"(vc\.mitsuba\.load\([^)]*)\)", r"\1, equirect_width=256)"),
]


def _blocks() -> list[tuple[int, str]]:
    """The README's Python blocks with the line each starts on."""
    text = README.read_text(encoding="utf-8")
    blocks = []
    for m in re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M):
        blocks.append((text.count("\n", 0, m.start()) + 2, m[1]))
    return blocks


BLOCKS = _blocks()


def shrink(code: str) -> str:
    """``code`` with the substitutions of :data:`SHRINK`."""
    for pattern, replacement in SHRINK:
        code = re.sub(pattern, replacement, code)
    return code


def test_the_readme_has_its_blocks():
    # Every block of the API section and the relighter's: a block lost to a broken fence
    # would silently stop being run.
    assert len(BLOCKS) >= 10, [line for line, _ in BLOCKS]
    assert all("import viscache_rs as vc" in code for _, code in BLOCKS)


def test_shrink_makes_sizes_small():
    assert shrink("vc.render(setup, spp=256, lb_spp=64, lbv_spp=8, time_budget=1.0)") == \
        "vc.render(setup, spp=min(256, 2), lb_spp=2, lbv_spp=2, time_budget=0.1)"
    assert shrink("look_at(e, t, width=256, height=192)") == "look_at(e, t, width=32, height=24)"
    assert shrink("VPLs.trace(setup, count=10_000)") == "VPLs.trace(setup, count=200)"
    assert shrink("vc.mitsuba.load(setup, camera=cam)") == \
        "vc.mitsuba.load(setup, camera=cam, equirect_width=256)"


@pytest.mark.parametrize("line, code", BLOCKS, ids=[f"line{line}" for line, _ in BLOCKS])
def test_readme_block_runs(line, code, tmp_path, monkeypatch):
    for module in re.findall(r"^(?:import|from) (\w+)", code, re.M):
        if importlib.util.find_spec(module) is None:
            pytest.skip(f"README.md line {line} needs {module}, which is not installed")
    load = vc.scenes.load

    def small_load(*args, **kwargs):
        setup = load(*args, **kwargs)
        setup.camera = setup.camera.with_resolution(*SMALL)
        texels = setup.envmap.texels()
        f = texels.shape[0] // SMALL_MAP
        if f > 1:  # box-filtered down to SMALL_MAP^2 texels
            setup.envmap = vc.EnvMap.from_octahedral(
                texels.reshape(SMALL_MAP, f, SMALL_MAP, f, 3).mean(axis=(1, 3)))
        return setup

    monkeypatch.setattr(vc.scenes, "load", small_load)
    monkeypatch.chdir(tmp_path)
    exec(compile(shrink(code), f"README.md:{line}", "exec"), {"__name__": "__readme__"})
