"""The experiments' output side: results directories, JSON, markdown, EXR/PNG images."""

import json

import numpy as np
import pytest
import viscache_rs as vc
from viscache_rs.experiments import ExperimentContext
from viscache_rs.io import write_exr


def test_write_exr_round_trips_through_an_envmap_reader(tmp_path):
    # A square power-of-two image reads back as an octahedral map, bit-exactly.
    rng = np.random.default_rng(1)
    img = rng.random((8, 8, 3), dtype=np.float32) * 1e3
    path = write_exr(tmp_path / "sub" / "img.exr", img)
    env = vc.EnvMap.from_exr(path)
    assert env.resolution == 8
    np.testing.assert_array_equal(env.texels(), img)


def test_write_exr_rejects_bad_images(tmp_path):
    with pytest.raises(ValueError, match="image"):
        write_exr(tmp_path / "a.exr", np.zeros((4, 4)))
    with pytest.raises(ValueError, match="image"):
        write_exr(tmp_path / "a.exr", np.zeros((0, 4, 3)))
    with pytest.raises(TypeError, match="image"):
        write_exr(tmp_path / "a.exr", np.full((2, 2, 3), "x"))


def test_context_writes_json_markdown_and_images(tmp_path):
    ctx = ExperimentContext(name="probe", out=tmp_path / "probe", quick=True, seed=3)
    ctx.record("ratio", np.float64(0.25))
    ctx.record("curve", np.arange(3))
    ctx.record("bad", float("nan"))
    text = ctx.table("Table", ["a", "b"], [[1, 0.123456], ["x", 2.0]])
    assert "| 1 | 0.1235 |" in text
    png = ctx.image("img", np.ones((4, 5, 3)))
    ctx.image("grey", np.zeros((4, 5)))
    ctx.finish()
    data = json.loads((tmp_path / "probe" / "results.json").read_text())
    assert data["ratio"] == 0.25 and data["curve"] == [0, 1, 2] and data["bad"] == "nan"
    assert data["quick"] is True and data["seed"] == 3 and data["seconds"] >= 0
    md = (tmp_path / "probe" / "results.md").read_text()
    assert md.startswith("# probe (quick)") and "| x | 2 |" in md
    assert png.read_bytes().startswith(b"\x89PNG")
    assert (tmp_path / "probe" / "img.exr").stat().st_size > 0
    assert (tmp_path / "probe" / "grey.exr").stat().st_size > 0


def test_unknown_experiment_names_itself():
    from viscache_rs import experiments

    with pytest.raises(ValueError, match="name"):
        experiments.run("no-such-experiment")
