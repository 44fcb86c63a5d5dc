"""Sweeps on Dask (vc.experiments.sweep, `viscache sweep`): rows that are what vc.render and
vc.metrics give by hand, the same on a cluster as in one process, the same after a worker
is lost, shared references and caches, bad sweep files refused before any work, Ctrl-C.

One LocalCluster (2 single-threaded worker processes) serves the module: it takes seconds
to start. Images are 32x24 with few samples."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest
import viscache_rs as vc
from viscache_rs.experiments import sweeps

pd = pytest.importorskip("pandas")
distributed = pytest.importorskip("distributed")

W, H = 32, 24
REF = {"method": "product", "spp": 256, "seed": 99}


def _points():
    """Eight points over two scenes: methods, sample counts, seeds and a shared cache."""
    common = {"width": W, "height": H, "reference": REF}
    pts = [{**common, "scene": "cornell", "method": m, "spp": spp, "seed": seed}
           for m, spp, seed in (("product", 4, 0), ("product", 16, 0), ("mis", 8, 3),
                                ("bsdf", 8, 1))]
    cache = {"preset": "low", "resolution": 16, "seed": 5}
    pts += [{**common, "scene": "garage", "method": "product", "spp": 8, "seed": 2},
            {**common, "scene": "garage", "method": "cv", "spp": 8, "seed": 2,
             "cache": cache, "label": "cv a=1"},
            {**common, "scene": "garage", "method": "cv", "spp": 8, "seed": 2,
             "cache": cache, "params": {"alpha": "estimate"}, "label": "cv a=est"},
            {**common, "scene": "garage", "method": "cv", "spp": 8, "seed": 2,
             "cache": {**cache, "preset": "high"}, "label": "cv high"}]
    return pts


def _same_rows(a, b):
    """The tables agree exactly but for the timing columns."""
    keep = [c for c in a.columns if c not in sweeps.TIMING_COLUMNS]
    assert list(a.columns) == list(b.columns)
    pd.testing.assert_frame_equal(a[keep], b[keep], check_exact=True)


@pytest.fixture(scope="module")
def cluster():
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as c, Client(c) as client:
        yield c, client


@pytest.fixture(scope="module")
def serial_table():
    return sweeps.sweep(_points(), sweeps.SERIAL)


def test_a_row_is_what_render_and_metrics_give_by_hand(serial_table):
    t = serial_table
    assert list(t["index"]) == list(range(8))
    assert list(t["label"][:4]) == ["product", "product", "mis", "bsdf"]
    # Point 2 by hand: its render and its scene's reference, then vc.metrics.
    setup = vc.scenes.load("cornell")
    cam = setup.camera.with_resolution(W, H)
    g = setup.scene.gbuffer(cam, jitter=False)
    ref = vc.render(setup, gbuffer=g, spp=256, method="product", seed=99, progress=False)
    res = vc.render(setup, gbuffer=g, spp=8, method="mis", seed=3, progress=False)
    row = t.iloc[2]
    assert row["relmse"] == vc.metrics.relmse(res.image, ref.image, ref.variance)
    assert row["relmse_raw"] == vc.metrics.relmse(res.image, ref.image)
    rgb = vc.metrics.relmse_per_channel(res.image, ref.image, ref.variance)
    assert [row["relmse_r"], row["relmse_g"], row["relmse_b"]] == list(rgb)
    assert row["variance"] == vc.metrics.relative_variance(res.variance, ref.image)
    assert row["mean_variance"] == vc.metrics.mean_variance(res.variance)
    assert row["efficiency"] == pytest.approx(1 / (row["relmse"] * row["render_seconds"]))
    assert row["spp"] == 8 and row["reference_spp"] == 256
    # Four times the samples, less error (cornell's product: far beyond its noise).
    assert 0 < t.iloc[1]["relmse"] < t.iloc[0]["relmse"]
    assert (t["relmse"] > 0).all() and np.isfinite(t["efficiency_total"]).all()


def test_a_shared_cache_is_built_once_and_each_point_starts_from_it(serial_table):
    t = serial_table
    cv = t[t["method"] == "cv"]
    a1, est, high = (cv.iloc[i] for i in range(3))
    # Both alphas read one build (one set of figures); the high preset has its own.
    assert a1["cache_seconds"] == est["cache_seconds"] > 0
    assert a1["records"] == est["records"] > 0
    assert high["cache"] != a1["cache"]
    assert t[t["method"] != "cv"]["cache_seconds"].eq(0).all()
    assert (cv["total_seconds"] == cv["render_seconds"] + cv["cache_seconds"]).all()
    # The point's image is that of a cache built by hand with the same settings.
    setup = vc.scenes.load("garage")
    cam = setup.camera.with_resolution(W, H)
    g = setup.scene.gbuffer(cam, jitter=False)
    cache = vc.VisibilityCache(setup.scene, preset="low", resolution=16)
    cache.build(gbuffer=g, seed=5, progress=False)
    res = vc.render(setup, gbuffer=g, spp=8, method="cv", cache=cache, seed=2, progress=False)
    assert a1["mean_variance"] == vc.metrics.mean_variance(res.variance)
    # The control variate pays: less variance than product at the same samples.
    assert a1["mean_variance"] < t.iloc[4]["mean_variance"]


def test_a_cluster_gives_the_rows_of_one_process(cluster, serial_table):
    _c, client = cluster
    seen = []
    table = sweeps.sweep(_points(), client, on_row=seen.append)
    _same_rows(table, serial_table)
    assert sorted(r["index"] for r in seen) == list(range(8))


def test_a_lost_worker_reruns_its_tasks_and_the_table_is_whole(cluster, serial_table):
    c, client = cluster
    # Heavier points, so that most are still to run when a worker dies.
    pts = [{**p, "spp": 8 * p["spp"]} for p in _points()] * 2
    pts = [{**p, "seed": p["seed"] + i} for i, p in enumerate(pts)]
    expected = sweeps.sweep(pts, sweeps.SERIAL)
    killed, after, in_flight, reran = [], [], [], []

    def suspicious(dask_scheduler):
        return sum(ts.suspicious > 0 for ts in dask_scheduler.tasks.values())

    def kill_one(row):
        if not killed:
            in_flight.append(sum(len(k) for k in client.processing().values()))
            pid = next(iter(client.run(os.getpid).values()))
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)
        else:
            after.append(row["index"])
            if len(after) == len(pts) - 1:  # the last row: the sweep still holds its tasks
                reran.append(client.run_on_scheduler(suspicious))

    table = sweeps.sweep(pts, client, on_row=kill_one)
    # The kill came mid-sweep, with tasks running, and every row still came.
    assert killed and in_flight[0] > 0 and len(after) == len(pts) - 1
    # The scheduler ran again the tasks that were running on the lost worker.
    assert reran[0] > 0
    _same_rows(table, expected)
    # The nanny brings the worker back for the tests after this one.
    client.wait_for_workers(2, timeout=60)


def test_renders_hold_no_gil():
    """A render on a thread leaves this thread running: its longest pause is a small part
    of the render (a render that held the GIL would pause it throughout)."""
    setup = vc.scenes.load("cornell")
    cam = setup.camera.with_resolution(64, 48)
    out = {}

    def work():
        out["res"] = vc.render(setup, cam, spp=256, method="mis", threads=1, progress=False)

    t = threading.Thread(target=work)
    ticks = [time.perf_counter()]
    t.start()
    while t.is_alive():
        ticks.append(time.perf_counter())
    seconds = ticks[-1] - ticks[0]
    assert seconds > 0.3, "the render is too short to tell"
    assert np.diff(ticks).max() < 0.5 * seconds


def _write(path, text):
    path.write_text(textwrap.dedent(text))
    return path


@pytest.mark.parametrize("body, match", [
    ('[[points]]\nscene = "cornell"\nmethod = "product"\nspp = 4\nsamples = 4\n',
     r"points\[0\]: unknown key 'samples'"),
    ('[defaults]\nwidht = 32\n[[points]]\nscene = "cornell"\nmethod = "mis"\nspp = 4\n',
     r"defaults: unknown key 'widht'"),
    ('name = "x"\n[[points]]\nscene = "cornell"\nmethod = "mis"\nspp = 4\n',
     r"unknown key 'name'"),
    ('[[points]]\nscene = "cornell"\nmethod = "mis"\nspp = 4\n'
     '[[points]]\nscene = "cornell"\nmethod = "mis"\nspp = 4\nparams = {alpah = 1}\n',
     r"points\[1\]\.params: unknown key 'alpah' for method 'mis'"),
    ('[[points]]\nscene = "garage"\nmethod = "cv"\nspp = 4\ncache = {presett = "low"}\n',
     r"points\[0\]\.cache: unknown key 'presett'"),
    ('[[points]]\nscene = "garage"\nmethod = "mis"\nspp = 4\ncache = {preset = "low"}\n',
     r"method 'mis' takes no VisibilityCache"),
    ('[[points]]\nscene = "nowhere"\nmethod = "mis"\nspp = 4\n', r"unknown scene 'nowhere'"),
    ('[[points]]\nscene = "cornell"\nmethod = "mis"\n', r"give 'spp' or 'time_budget'"),
    ('[[points]]\nscene = "cornell"\nmethod = "mis"\nspp = 0\n', r"spp: must be at least 1"),
    ('[[points]\nscene = "cornell"\n', r"not a valid TOML file"),
    ('[[points]]\nscene = "cornell"\nmethod = "mis"\nspp = 4\nreference = {spp = 8, s = 1}\n',
     r"reference: unknown key 's'"),
])
def test_a_bad_sweep_file_is_refused_naming_the_file_and_key(tmp_path, body, match):
    path = _write(tmp_path / "bad.toml", body)
    with pytest.raises((ValueError, TypeError), match=match) as e:
        sweeps.load(path)
    assert str(e.value).startswith(str(path))


def test_a_json_sweep_file_reads_like_its_toml(tmp_path):
    pts = [{"scene": "cornell", "method": "mis", "spp": 4, "seed": 1},
           {"scene": "garage", "method": "cv", "spp": 2, "cache": {"preset": "low"}}]
    j = tmp_path / "s.json"
    j.write_text(json.dumps({"defaults": {"width": 16, "height": 12}, "points": pts}))
    t = _write(tmp_path / "s.toml", """\
        [defaults]
        width = 16
        height = 12
        [[points]]
        scene = "cornell"
        method = "mis"
        spp = 4
        seed = 1
        [[points]]
        scene = "garage"
        method = "cv"
        spp = 2
        cache = {preset = "low"}
        """)
    a, b = sweeps.load(j), sweeps.load(t)
    assert a == b and a[0]["width"] == 16 and a[1]["cache"] == {"preset": "low", "seed": 0}
    bare = tmp_path / "list.json"
    bare.write_text(json.dumps(pts))
    assert sweeps.load(bare)[0]["width"] == 64  # the default size
    with pytest.raises(ValueError, match=r"list\.json: points\[1\]: unknown key 'sp'"):
        bare.write_text(json.dumps([pts[0], {**pts[0], "sp": 3}]))
        sweeps.load(bare)


def test_points_in_python_are_checked_before_any_work():
    with pytest.raises(ValueError, match=r"^points\[1\]: unknown key 'sed'"):
        sweeps.sweep([{"scene": "cornell", "method": "mis", "spp": 1},
                      {"scene": "cornell", "method": "mis", "spp": 1, "sed": 2}], "no-client")
    with pytest.raises(ValueError, match="has no points"):
        sweeps.sweep([], sweeps.SERIAL)


def test_a_value_the_renderer_refuses_names_the_point(cluster):
    _c, client = cluster
    pts = [{"scene": "cornell", "method": "mis", "spp": 1, "width": 8, "height": 6,
            "reference": False},
           {"scene": "garage", "method": "cv", "spp": 1, "width": 8, "height": 6,
            "reference": False, "params": {"alpha": 7.0}, "cache": {"preset": "low"}}]
    for where in (sweeps.SERIAL, client):
        with pytest.raises(ValueError, match=r"^points\[1\] \(cv\): alpha"):
            sweeps.sweep(pts, where)


def test_the_cli_writes_the_table_and_the_plot(cluster, tmp_path, serial_table):
    from viscache_rs.cli import main

    c, _client = cluster
    cfg = tmp_path / "sweep.json"
    cfg.write_text(json.dumps(_points()[:4]))
    out = tmp_path / "out"
    assert main(["sweep", str(cfg), "--scheduler", c.scheduler_address, "--out", str(out),
                 "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["efficiency.png", "sweep.parquet"]
    table = pd.read_parquet(out / "sweep.parquet")
    _same_rows(table, serial_table.iloc[:4].reset_index(drop=True))
    assert (out / "efficiency.png").read_bytes().startswith(b"\x89PNG")


def test_the_cli_refuses_a_bad_file_and_writes_nothing(tmp_path, capsys):
    from viscache_rs.cli import main

    cfg = _write(tmp_path / "bad.toml", '[[points]]\nscene = "cornell"\nmethod = "mis"\n'
                 'spp = 4\nthreads = 2\n')
    out = tmp_path / "out"
    assert main(["sweep", str(cfg), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "bad.toml: points[0]: unknown key 'threads'" in err
    assert not out.exists()


def test_write_leaves_whole_files_or_none(tmp_path, serial_table, monkeypatch):
    out = tmp_path / "out"
    sweeps.write(serial_table, out)
    before = (out / "sweep.parquet").read_bytes()

    def broken(_table):
        raise RuntimeError("plot failed")

    monkeypatch.setattr(sweeps, "plot", broken)
    with pytest.raises(RuntimeError):
        sweeps.write(serial_table.iloc[:2], out)
    # Nothing was written: the previous table is whole and no temporary is left.
    assert (out / "sweep.parquet").read_bytes() == before
    assert sorted(p.name for p in out.iterdir()) == ["efficiency.png", "sweep.parquet"]

def test_the_tradeoff_experiment_on_a_cluster_gives_its_rows_in_process(cluster, tmp_path,
                                                                         monkeypatch):
    from viscache_rs import experiments
    from viscache_rs.experiments import tradeoff

    def tiny(quick):
        return {"scenes": ["garage"], "width": 24, "height": 18, "reference_spp": 64,
                "spp": [2, 8], "configs": [tradeoff.CV_CONFIGS[2], tradeoff.CV_CONFIGS[5]]}

    monkeypatch.setattr(tradeoff, "settings", tiny)
    _c, client = cluster
    here = experiments.run("tradeoff", quick=True, out=tmp_path / "a", progress=False)
    there = experiments.run("tradeoff", quick=True, out=tmp_path / "b", progress=False,
                            client=client)
    timing = {"render_seconds", "cache_seconds", "total_seconds", "efficiency",
              "efficiency_total"}
    a, b = here.results["garage/rows"], there.results["garage/rows"]
    assert len(a) == len(b) == 6
    for x, y in zip(a, b, strict=True):
        assert {k: v for k, v in x.items() if k not in timing} == \
            {k: v for k, v in y.items() if k not in timing}
    assert (tmp_path / "b" / "tradeoff" / "tradeoff_garage.png").exists()



def test_the_variance_table_on_a_cluster_gives_its_in_process_ratios(cluster, tmp_path,
                                                                      monkeypatch):
    from viscache_rs import experiments
    from viscache_rs.experiments import variance_table

    monkeypatch.setattr(variance_table, "settings", lambda quick: {
        "width": 32, "height": 24, "spp": [2, 4], "scenes": ["garage"], "equal_time_spp": 4})
    monkeypatch.setattr(variance_table, "REPEATS", 1)
    monkeypatch.setitem(variance_table.CACHE, "garage", {"resolution": 16, "preset": "low"})
    _c, client = cluster
    here = experiments.run("variance-table", quick=True, out=tmp_path / "a", progress=False)
    there = experiments.run("variance-table", quick=True, out=tmp_path / "b", progress=False,
                            client=client)
    a, b = here.results["scenes"]["garage"]["rows"], there.results["scenes"]["garage"]["rows"]
    for key in ("var_product", "var_cv", "ratio_cv", "ratio_rgb_cv_est", "mean_alpha_est"):
        assert [r[key] for r in a] == [r[key] for r in b], key
    # (Fig. 13's product spp follows the measured seconds, so its ratio may differ.)
    assert there.results["equal_time"]["render"]["variance_ratio"] > 0
    # The images came back from the workers.
    assert (tmp_path / "b" / "variance-table" / "garage_cv_2spp.exr").exists()


CHILD = textwrap.dedent(
    """
    import signal, sys
    signal.signal(signal.SIGINT, signal.default_int_handler)
    from viscache_rs.experiments import sweeps
    pts = [{{"scene": "garage", "method": "product", "spp": 4096, "seed": s,
             "width": 64, "height": 48, "reference": False}} for s in range(8)]
    client = {client}
    print("ready", flush=True)
    try:
        sweeps.sweep(pts, client)
        print("finished", flush=True)
    except KeyboardInterrupt:
        print("interrupted", flush=True)
    """
)


@pytest.mark.parametrize("where", ["serial", "cluster"])
def test_ctrl_c_stops_a_sweep(cluster, where):
    c, client = cluster
    arg = repr(sweeps.SERIAL if where == "serial" else c.scheduler_address)
    child = subprocess.Popen([sys.executable, "-c", CHILD.format(client=arg)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    watchdog = threading.Timer(120.0, child.kill)
    watchdog.start()
    try:
        assert child.stdout.readline().strip() == "ready"
        # Well inside the sweep: its tasks are running.
        deadline = time.monotonic() + 30
        while where == "cluster" and not any(client.processing().values()):
            assert time.monotonic() < deadline, "the sweep did not start"
            time.sleep(0.05)
        time.sleep(1.0)
        sent = time.perf_counter()
        child.send_signal(signal.SIGINT)
        line = child.stdout.readline().strip()
        waited = time.perf_counter() - sent
        assert line == "interrupted", child.stderr.read()
        assert waited < 5.0, f"{waited:.2f} s after SIGINT"
        assert child.wait(timeout=60) == 0
    finally:
        watchdog.cancel()
        child.kill()
        child.wait()
    if where == "cluster":
        # The sweep's tasks were cancelled: the cluster is free within a render's end.
        deadline = time.monotonic() + 30
        while any(client.processing().values()):
            assert time.monotonic() < deadline, client.processing()
            time.sleep(0.1)

