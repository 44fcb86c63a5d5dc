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


def _tiny_animation(quick):
    return {"frames": [0, 10, 20], "width": 32, "height": 24, "spp": 2, "preset": "low",
            "resolution": 16, "validate_rays": 8}


def test_animation_experiment_smoke(tmp_path, monkeypatch):
    from viscache_rs import experiments
    from viscache_rs.experiments import animation

    monkeypatch.setattr(animation, "settings", _tiny_animation)
    assert animation.DESCRIPTION.splitlines()[0].startswith("N frames")
    experiments.run("animation", quick=True, out=tmp_path, seed=1, threads=2, progress=False)
    data = json.loads((tmp_path / "animation" / "results.json").read_text())
    frames = data["frames"]
    assert [f["frame"] for f in frames] == [0, 10, 20]
    for f in frames:
        assert f["records"] > 0 and f["fresh_records"] > 0
        for key in ("reuse_rays_per_pixel", "fresh_rays_per_pixel", "reuse_variance",
                    "fresh_variance", "product_variance", "reuse_ratio", "fresh_ratio",
                    "reuse_render_seconds", "reuse_cache_seconds", "fresh_cache_seconds"):
            assert np.isfinite(f[key]) and f[key] >= 0, key
        assert f["reuse_ratio"] > 0 and f["fresh_ratio"] > 0
    # The first frame builds the whole cache, like the fresh one; later frames only refill.
    assert frames[0]["inserted"] == frames[0]["records"]
    assert frames[0]["evicted_by_misses"] == 0
    assert frames[0]["reuse_rays_per_pixel"] == pytest.approx(frames[0]["fresh_rays_per_pixel"])
    # The sphere moves: records go stale and are evicted, and the refill costs less.
    assert sum(f["evicted_by_misses"] for f in frames[1:]) > 0
    assert all(f["validate_misses"] > 0 for f in frames[1:])
    assert all(f["reuse_rays_per_pixel"] < f["fresh_rays_per_pixel"] for f in frames[1:])
    md = (tmp_path / "animation" / "results.md").read_text()
    assert "## Per frame" in md and "| 20 |" in md
    for name in ("animation.png", "frame000_reuse.png", "frame020_reuse.png"):
        assert (tmp_path / "animation" / name).read_bytes().startswith(b"\x89PNG")


def _tiny_tradeoff(quick):
    from viscache_rs.experiments import tradeoff

    return {"scenes": ["garage"], "width": 24, "height": 18, "reference_spp": 64,
            "spp": [2, 8], "configs": [tradeoff.CV_CONFIGS[2], tradeoff.CV_CONFIGS[5]]}


def test_tradeoff_experiment_smoke(tmp_path, monkeypatch):
    from viscache_rs import experiments
    from viscache_rs.experiments import tradeoff

    monkeypatch.setattr(tradeoff, "settings", _tiny_tradeoff)
    assert "relMSE on RGB against seconds" in tradeoff.DESCRIPTION.splitlines()[0]
    # The default cache is a point of every plot, beside the presets.
    assert [c[0] for c in tradeoff.CV_CONFIGS[:2]] == ["cv auto a=1", "cv auto a=est"]
    assert tradeoff.CV_CONFIGS[2][0] == "cv a=1 low" and tradeoff.CV_CONFIGS[5][0] == "cv a=est low"
    experiments.run("tradeoff", quick=True, out=tmp_path, seed=2, threads=2, progress=False)
    data = json.loads((tmp_path / "tradeoff" / "results.json").read_text())
    rows = data["garage/rows"]
    assert [(r["config"], r["spp"]) for r in rows] == [
        (c, s) for c in ("product", "cv a=1 low", "cv a=est low") for s in (2, 8)]
    for r in rows:
        for key in ("render_seconds", "total_seconds", "mse_raw", "variance"):
            assert np.isfinite(r[key]) and r[key] > 0, key
        assert len(r["mse_rgb"]) == 3
        assert r["total_seconds"] == pytest.approx(r["render_seconds"] + r["cache_seconds"])
        assert (r["cache_seconds"] > 0) == (r["config"] != "product")
        assert (r["records"] > 0) == (r["config"] != "product")
    # More samples, less error (4x the samples; generous for a tiny image).
    for c in ("product", "cv a=1 low", "cv a=est low"):
        mse = [r["mse_raw"] for r in rows if r["config"] == c]
        assert mse[1] < mse[0]
    # The cache is built once per preset and shared by both alphas.
    assert data["garage/cache/low/32"]["records"] > 0
    assert len({r["cache_seconds"] for r in rows if r["config"] != "product"}) == 1
    assert data["garage/reference"]["spp"] == 64
    summary = data["summary"]["garage"]
    assert summary["product"]["mse_ratio_to_product"] == 1
    assert all(v["mse_ratio_to_product"] > 0 for v in summary.values())
    md = (tmp_path / "tradeoff" / "results.md").read_text()
    assert "## garage: error against time" in md and "| cv a=est low | 8 |" in md
    assert (tmp_path / "tradeoff" / "tradeoff_garage.png").read_bytes().startswith(b"\x89PNG")


def test_variance_table_experiment_smoke(tmp_path, monkeypatch):
    from viscache_rs import experiments
    from viscache_rs.experiments import variance_table

    def tiny(quick):
        return {"width": 32, "height": 24, "spp": [2, 4], "scenes": ["garage"],
                "equal_time_spp": 4}

    monkeypatch.setattr(variance_table, "settings", tiny)
    monkeypatch.setattr(variance_table, "REPEATS", 1)
    monkeypatch.setitem(variance_table.CACHE, "garage", {"resolution": 16, "preset": "low"})
    ctx = experiments.run("variance-table", quick=True, out=tmp_path, progress=False)
    data = json.loads((tmp_path / "variance-table" / "results.json").read_text())
    rows = data["scenes"]["garage"]["rows"]
    assert [r["spp"] for r in rows] == [2, 4]
    for r in rows:
        assert r["time_product"] > 0 and r["time_cv"] > 0
        assert 0 < r["ratio_cv"] < 1 and 0 < r["ratio_cv_est"] < 1
    assert data["scenes"]["garage"]["build"]["records"] > 0
    eq = data["equal_time"]
    assert eq["render"]["product_spp"] >= 1 and eq["with_build"]["variance_ratio"] > 0
    md = (tmp_path / "variance-table" / "results.md").read_text()
    assert "Table 3" in md and "Table 2" in md and "Fig. 13" in md
    assert (tmp_path / "variance-table" / "variance_table.png").exists()
    assert ctx.results["experiment"] == "variance-table"


def test_relight_experiment_smoke(tmp_path, monkeypatch):
    from viscache_rs import experiments
    from viscache_rs.experiments import relight

    monkeypatch.setattr(relight, "SIZES", {True: (16, 12), False: (16, 12)})
    monkeypatch.setattr(relight, "V_SPP", 32)
    monkeypatch.setattr(relight, "REFERENCE_SPP", {True: 64, False: 64})
    monkeypatch.setattr(relight, "EQUAL_TIME_SECONDS", {True: 0.05, False: 0.05})
    cases = list(relight._cases(quick=True))
    assert [c[0] for c in cases][:3] == ["garage_rot45", "garage_sky", "cornell_red_green"]
    monkeypatch.setattr(relight, "_cases", lambda quick: iter([cases[0], cases[2]]))
    experiments.run("relight", quick=True, out=tmp_path, seed=1, threads=2, progress=False)
    data = json.loads((tmp_path / "relight" / "results.json").read_text())
    rec = data["garage_rot45"]
    for source in ("pixels", "cache"):
        assert 0 <= rec[f"bound_holds_{source}_lb64"] <= 1
        for thr in relight.THRESHOLDS:
            row = rec[f"equal_time_{source}_{thr}"]
            assert row["seconds"] > 0 and row["classical_spp"] >= 1 and 0 <= row["mean_t"] <= 1
            assert row["blend_lbv_spp"] == 8
            # SBF's classical <LBV>, given the blend's seconds, takes its first pass at least.
            # (relMSE less the reference's own variance share may be below 0 at this size.)
            assert row["lbv_spp"] >= 8 and np.isfinite(row["relmse_lbv"])
            assert row["ratio_lbv"] == row["relmse"] / row["relmse_lbv"]
        longer = rec[f"equal_time_{source}_{relight.THRESHOLDS[-1]}_budget"]
        assert longer["blend_lbv_spp"] >= 8 and longer["seconds"] > 0
    assert 0 <= rec["camera_move_bound_holds"] <= 1
    # The box's area lights read records that see them in the cache_lights rows, also
    # after the camera moved (their t above 0: without <V> it would be 0).
    box = data["cornell_red_green"]
    assert 0 <= box["bound_holds_cache_lights_lb64"] <= 1
    assert 0 <= box["equal_time_cache_lights_0.25"]["mean_t"] <= 1
    assert 0 <= box["camera_move_bound_holds"] <= 1 and box["camera_move_mean_t_area"] > 0
    over = rec["overhead"]
    assert over["first_frame_seconds"] > 0 and over["later_lbv_spp"] >= 0
    # Two 16-bit counts, and the map's 32 V-sample bits (one word) for its one light.
    assert rec["overhead"]["bytes_per_pixel_and_light"] == 4 + 4
    md = (tmp_path / "relight" / "results.md").read_text()
    assert "Where the estimated bound holds" in md and "| garage_rot45 | cache | 0.25 |" in md


def test_the_edge_band_grows_from_the_creases():
    from viscache_rs.experiments.irradiance_cache import edge_band

    setup = vc.scenes.load("cornell")
    cam = setup.camera.with_resolution(64, 48)
    bands = [edge_band(setup, cam, 2, width=w) for w in (0, 1, 4)]
    # Width 0: the creases alone (the box's corners and the blocks' edges).
    assert 0 < bands[0].sum() < 0.2 * bands[0].size
    for thin, wide in zip(bands[:-1], bands[1:], strict=True):
        assert (wide >= thin).all() and wide.sum() > thin.sum()
    hits = setup.scene.gbuffer(cam, jitter=False)["object"] >= 0
    assert not (bands[-1] & ~hits).any()


def test_irradiance_cache_experiment_smoke(tmp_path, monkeypatch):
    from viscache_rs import experiments
    from viscache_rs.experiments import irradiance_cache

    def tiny(quick):
        return {"scenes": [("cornell", None)], "width": 24, "height": 18,
                "reference_spp": 256, "a": [0.2, 0.4], "gradients": ["none", "both"],
                "clamp": [True], "path_budgets": [1.0], "interpolation_size": (16, 12),
                "scaling": [(16, 12), (32, 24), (64, 48)]}

    monkeypatch.setattr(irradiance_cache, "settings", tiny)
    assert irradiance_cache.settings(True)["scenes"] == [("cornell", None)]
    experiments.run("irradiance-cache", quick=True, out=tmp_path, seed=1, threads=2,
                    progress=False)
    out = tmp_path / "irradiance-cache"
    data = json.loads((out / "results.json").read_text())
    d = data["cornell/default"]
    assert d["records"] > 0 and d["build_complete"] and 0 <= d["misses"] < d["lookups"]
    assert d["hemisphere_rays"] % (16 * 64) == 0
    assert d["hemisphere_rays"] >= d["records"] * 16 * 64
    assert 0 < d["build_seconds"] < d["seconds"]
    assert np.isfinite(d["relmse"]) and len(d["relmse_rgb"]) == 3
    grid = data["cornell/grid"]
    assert [(r["a"], r["gradients"]) for r in grid] == [
        (0.2, "none"), (0.2, "both"), (0.4, "none"), (0.4, "both")]
    # Gradients change the interpolation, not the records.
    assert grid[0]["records"] == grid[1]["records"] > grid[2]["records"] == grid[3]["records"]
    assert all(0 <= r["misses"] < r["lookups"] for r in grid)
    band = data["cornell/edge_band"]
    assert 0 < band["pixels"] <= 24 * 18 and band["clamping_gain"] == []  # no clamp=off row
    assert all(np.isfinite(r["edge_relmse"]) for r in grid)
    # The interpolation's own error: gradients lower it (measured 2-3x on cornell), and a
    # per-pixel cache gives every point its own record.
    for a in (0.2, 0.4):
        none, both = (r["interpolation_relmse"] for r in grid if r["a"] == a)
        assert 0 < both < none
    assert data["cornell/per_pixel"]["own_record"] == 1
    assert data["cornell/per_pixel"]["record_noise"] > 0
    gains = data["cornell/gradient_gain_interpolation"]
    assert [(g["a"], g["gradients"]) for g in gains] == [(0.2, "both"), (0.4, "both")]
    eq = {o["method"]: o for o in data["cornell/equal_time"]}
    assert set(eq) == {"path", "vpl", "vf"} and eq["path"]["spp"] >= 1
    assert eq["vf"]["budget_factor"] == pytest.approx(eq["vf"]["seconds"] / d["seconds"])
    assert eq["path"]["mean_spp"] >= eq["path"]["spp"]
    assert all(o["seconds"] > 0 and np.isfinite(o["relmse"]) for o in eq.values())
    whole = data["cornell/whole_image"]
    assert whole["path"]["seconds"] > 0 and whole["irradiance_cache"]["records"] > 0
    rows = data["cornell/scaling"]["rows"]
    assert [r["records"] for r in rows] == sorted(r["records"] for r in rows)
    assert data["cornell/scaling"]["ratio"] == rows[-1]["records"] / rows[0]["records"]
    summary = data["summary"]["cornell"]
    assert summary["record_ratio"] >= 1
    # A ratio of relMSEs is given only where both are positive (each less its
    # reference's noise share), else None and its target undecided.
    for key, met in (("relmse_ratio_to_path", "path_target_met"),
                     ("whole_image_ratio_to_path", None)):
        r = summary[key]
        assert r is None or r > 0
        if met:
            assert summary[met] is (None if r is None else r <= 0.1)
    # Against VF: the relMSE ratio where VF took at least the cache's time, else the
    # efficiency's.
    vf_ratio, vf_met = summary["relmse_ratio_to_vf"], summary["vf_target_met"]
    if vf_ratio is not None:
        by = (vf_ratio if eq["vf"]["seconds"] >= d["seconds"]
              else 1 / summary["efficiency_gain_over_vf"])
        assert vf_met is (by <= 0.5)
    md = (out / "results.md").read_text()
    assert "## Targets (issue 62 §5)" in md and "| cornell | 0.4 | both | on |" in md
    for name in ("cornell_records.png", "cornell_relmse_vs_a.png", "cornell_equal_time.png",
                 "records_vs_pixels.png", "cornell_cache.png"):
        assert (out / name).read_bytes().startswith(b"\x89PNG"), name
    # The reference is kept and read again by a rerun.
    assert len(list(out.glob("reference_cornell_path_24x18_256spp_seed1.npz"))) == 1
    assert data["cornell/reference"]["cached"] is False


def test_vf_experiment_smoke(tmp_path, monkeypatch):
    from viscache_rs import experiments
    from viscache_rs.experiments import vf

    quick = vf.settings(True)
    assert quick["scenes"] == [("cornell", None)] and quick["floors"] == (10, 30, 50)

    def tiny(quick):
        return {"scenes": [("cornell", None)], "width": 24, "height": 18,
                "reference_spp": 64,
                "table1": {"cornell": {"size": (32, 32), "marching": [16]}},
                "scene_params": {"cornell": {"proxies": 2000, "voxels": 4}},
                "knobs": [{"rays_per_pixel": 4}, {"rays_per_pixel": 16},
                          {"rays_per_pixel": 16, "filter": 1}],
                "floors": (30,), "floor_size": (16, 12), "floor_spp": 32,
                "flicker": {"frames": 3, "degrees": 0.5, "size": (16, 12),
                            "reference_spp": 16}}

    monkeypatch.setattr(vf, "settings", tiny)
    monkeypatch.setattr(vf, "PAPER_TABLE_1", {("cornell", 16): vf.PAPER_TABLE_1[
        ("cornell", 64)]})
    monkeypatch.setattr(vf, "PAPER_FRAME_SECONDS", {("cornell", 16): 0.435})
    experiments.run("vf", quick=True, out=tmp_path, seed=1, threads=2, progress=False)
    out = tmp_path / "vf"
    data = json.loads((out / "results.json").read_text())
    t1 = data["table1/cornell/16"]
    for k in vf.STAGES:
        assert t1[f"{k}_ms"] >= 0
    assert t1["marching_ms"] > 0 and t1["illumination_ms"] > 0
    assert t1["marching"] == [16, 16] and t1["target_met"] in (True, False)
    d = data["cornell/default"]
    assert 1500 < d["proxies"] < 2500 and np.isfinite(d["relmse"]) and d["efficiency"] > 0
    assert data["cornell/combined"]["relmse"] < 1
    eq = {o["method"]: o for o in data["cornell/equal_time"]}
    assert set(eq) == {"path", "vpl"} and all(o["seconds"] > 0 for o in eq.values())
    knobs = data["cornell/knobs"]
    assert [(r["rays_per_pixel"], r["filter"]) for r in knobs] == [(4, 7), (16, 7), (16, 1)]
    # The 7x7 filter only adds voxels to the lists.
    assert knobs[1]["mean_list_after"] >= knobs[2]["mean_list_after"]
    assert all(r["path"]["seconds"] > 0 and r["vpl"]["seconds"] > 0 for r in knobs)
    floor = data["floors/30"]
    assert floor["exponent"] == 30 and np.isfinite(floor["relmse"])
    flick = data["cornell/flicker"]
    assert flick["frames"] == 3 and len(flick["vf_relmse_per_frame"]) == 3
    # Consecutive frames of a pan differ; a 16-spp path differs more than its mean motion.
    assert flick["vf"] > 0 and flick["reference"] > 0 and flick["path"] > 0
    summary = data["summary"]
    assert summary["targets"]["bias"] == d["relmse"]
    assert set(summary["targets"]["floors_equal_time"]) == {"30"}
    md = (out / "results.md").read_text()
    assert "## Table 1: per-stage milliseconds" in md and "| cornell | 16x16 |" in md
    for name in ("cornell_strip.png", "cornell_relmse_vs_seconds.png", "cornell_vf.png"):
        assert (out / name).read_bytes().startswith(b"\x89PNG"), name


def test_importance_cache_experiment_smoke(tmp_path, monkeypatch):
    from viscache_rs import experiments
    from viscache_rs.experiments import importance_cache

    def tiny(quick):
        return {"sets": [("cornell", 300)], "width": 16, "height": 12, "base_spp": 2,
                "budgets": [1.0], "area_reference_spp": 16}

    monkeypatch.setattr(importance_cache, "settings", tiny)
    experiments.run("importance-cache", quick=True, out=tmp_path, seed=1, threads=2,
                    progress=False)
    out = tmp_path / "importance-cache"
    data = json.loads((out / "results.json").read_text())
    exact = data["cornell/exact"]
    assert exact["lights"] > 0 and exact["spp"] == 1 and exact["seconds"] > 0
    build = data["cornell/build"]
    # Rows: at most 12 bytes per light and record (fewer where sparse), plus the index.
    assert build["records"] > 0 and 0 < build["bytes_per_light_record"] < 12 + 10_000 / 300
    claims = data["cornell/row_claims"]
    # Each pixel's mass is split among the rows; pixels without a surface give none.
    assert set(claims) == set("FUBC") and 0 < sum(claims.values()) <= 1 + 1e-9
    names = [m for m, _, _ in importance_cache.METHODS]
    fixed = data["cornell/fixed_samples"]
    assert [r["method"] for r in fixed] == names
    eq = data["cornell/equal_time"]
    assert [r["method"] for r in eq] == names
    assert all(np.isfinite(r["relmse"]) and r["seconds"] > 0 and r["spp"] >= 1 for r in eq)
    # The unbiased columns' means agree with the exact sum's (green channel, loosely: a
    # tiny image at few samples).
    for r in eq:
        if r["method"] in ("uniform", "power", "unoccluded", "balance", "alpha_max"):
            assert 0.5 < r["mean_ratio"][1] < 2.0, r
    s = data["summary"]["cornell"]
    assert s["ratio_uniform"] == pytest.approx(
        next(r for r in eq if r["method"] == "alpha_max")["relmse"]
        / next(r for r in eq if r["method"] == "uniform")["relmse"])
    assert set(s["met"]) == {"uniform", "power", "balance", "best_row", "exact_fraction",
                             "build", "bytes"}
    md = (out / "results.md").read_text()
    assert "Targets (issue 65 §5)" in md
    for name in ("cornell_exact.png", "cornell_alpha_max.png", "cornell_row_claims.png",
                 "cornell_relmse_vs_seconds.png"):
        assert (out / name).exists(), name


def test_proxies_experiment_smoke(tmp_path, monkeypatch):
    from viscache_rs import experiments
    from viscache_rs.experiments import proxies

    def tiny(quick):
        return {"scenes": [("cornell", "dense_blocks", ("boxes", "spheres"))],
                "width": 12, "height": 9, "base_spp": 2, "reference_spp": 16,
                "budgets": [1.0], "modes": ("equal", "optimal")}

    monkeypatch.setattr(proxies, "settings", tiny)
    experiments.run("proxies", quick=True, out=tmp_path, seed=1, threads=2, progress=False)
    out = tmp_path / "proxies"
    data = json.loads((out / "results.json").read_text())
    made = data["cornell-dense_blocks/proxies"]
    # The two blocks are the dense objects; a box each, and spheres inside each.
    assert len(made["objects"]) == 2 and made["object_triangles"] == 2 * 81_920
    kinds = {s["proxies"]: s for s in made["sets"]}
    assert kinds["boxes"]["triangles"] == 24 and kinds["boxes"]["kind"] == "outside"
    assert kinds["spheres"]["kind"] == "inside" and kinds["spheres"]["triangles"] > 0
    eq = data["cornell-dense_blocks/equal_time"]
    names = ["exact"] + [f"{k}/{m}" for k in ("boxes", "spheres") for m in ("equal", "optimal")]
    assert [r["method"] for r in eq] == names
    assert all(np.isfinite(r["relmse"]) and r["seconds"] > 0 and r["spp"] >= 1 for r in eq)
    stochastic = [r for r in eq if r["method"] != "exact"]
    assert all(r["proxy_rays_per_pixel"] > 0 for r in stochastic)
    assert "cornell-dense_blocks" in data["summary"]
    assert (out / "cornell-dense_blocks_relmse_vs_seconds.png").read_bytes().startswith(b"\x89PNG")
