"""Ctrl-C in every phase of every long call, with no progress reports (``progress=False``):
SIGINT, sent to this process by a timer at several moments of a call, raises
KeyboardInterrupt within a watchdog of a few seconds (the target is 0.5 s; the bound is
generous so that a loaded machine cannot fail it by chance), the call did not finish, and
the objects it used still work. Time budgets: each method ends within 10% of its budget
plus a small constant, and its stats say how long it took.

Sizes are chosen so that each call runs for a second or more when not interrupted: the
signal lands inside it, and the test asserts that it did. Interrupted calls return at
once, so the file takes a few seconds; nothing left running in the background (a BVH
build the builders cannot stop) outlives its test by more than a second of one core."""

from __future__ import annotations

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

LIMIT_S = 3.0


@pytest.fixture(autouse=True)
def sigint_raises():
    """A shell starts background jobs with SIGINT ignored; a user's terminal raises."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def interrupt(call, at: float) -> float:
    """Runs `call`, sending SIGINT `at` seconds in; returns the seconds from the signal to
    the KeyboardInterrupt, after asserting the call was still running."""
    sent = []

    def send():
        sent.append(time.perf_counter())
        os.kill(os.getpid(), signal.SIGINT)

    timer = threading.Timer(at, send)
    timer.start()
    try:
        try:
            call()
        except KeyboardInterrupt:
            caught = time.perf_counter()
        else:
            timer.cancel()
            pytest.fail(f"the call finished before SIGINT at {at} s: make it longer")
    finally:
        timer.cancel()
    assert sent, "KeyboardInterrupt without the signal"
    waited = caught - sent[0]
    print(f"KeyboardInterrupt {waited:.3f} s after SIGINT at {at} s")
    assert waited < LIMIT_S, f"{waited:.2f} s after SIGINT"
    return waited


@pytest.fixture(scope="module")
def garage():
    return vc.scenes.load("garage")


@pytest.mark.parametrize("at", [0.05, 0.4, 1.0])
def test_cache_build_stops_in_every_phase(garage, at):
    # The G-buffer, the coherence check and bootstrap, then the waves: 1.0 s at 640x480 on
    # an idle 2-core Zen 4, so 1024x768 (2.6x the pixels) to outlast the last SIGINT.
    cam = garage.camera.with_resolution(1024, 768)
    cache = vc.VisibilityCache(garage.scene, preset="medium", resolution=64)
    interrupt(lambda: cache.build(cam, progress=False), at)
    small = garage.camera.with_resolution(16, 12)
    cache.build(small, progress=False)
    assert len(cache) > 0
    r = vc.render(garage, small, spp=2, method="cv", cache=cache, progress=False)
    assert np.isfinite(r.image).all()


@pytest.fixture(scope="module")
def rays(garage):
    """4M rays from the garage's eye (0.9 s of intersect on 2 cores)."""
    n = 4_000_000
    o = np.broadcast_to(np.asarray(garage.camera.eye, np.float32), (n, 3))
    d = np.random.default_rng(0).random((n, 3), dtype=np.float32) - 0.5
    return np.ascontiguousarray(o), d


@pytest.mark.parametrize("at", [0.1, 0.3])
def test_gbuffer_and_intersect_stop(garage, rays, at):
    cam = garage.camera.with_resolution(3072, 3072)
    interrupt(lambda: garage.scene.gbuffer(cam), at)
    o, d = rays
    interrupt(lambda: garage.scene.intersect(o, d), at)
    hits = garage.scene.intersect(o[:100], d[:100])
    assert hits["t"].shape == (100,)


@pytest.mark.parametrize("at", [0.1, 0.4])
def test_vpl_trace_stops(garage, at):
    interrupt(lambda: vc.VPLs.trace(garage, 1_000_000, depth=8), at)
    assert len(vc.VPLs.trace(garage, 64)) > 0


@pytest.mark.parametrize("method", ["path", "vpl"])
def test_renders_stop(garage, method):
    cam = garage.camera.with_resolution(320, 240)
    interrupt(lambda: vc.render(garage, cam, spp=10_000, method=method, progress=False), 0.25)
    r = vc.render(garage, cam.with_resolution(8, 6), spp=1, method=method, progress=False)
    assert r.image.shape == (6, 8, 3)


def test_envmap_from_equirect_stops():
    # 24 s when not interrupted (16M texels of 64 points each).
    rgb = np.ones((1024, 2048, 3), np.float32)
    interrupt(lambda: vc.EnvMap.from_equirect(rgb, resolution=4096), 0.3)
    assert vc.EnvMap.from_equirect(rgb[:64, :128], resolution=16).resolution == 16


def test_envmap_to_equirect_stops():
    # Pixels far smaller than texels (the gathered path): 2.4 s when not interrupted.
    env = vc.EnvMap.constant(1.0, resolution=256)
    interrupt(lambda: env.to_equirect(8192, 4096), 0.2)
    assert env.to_equirect(64, 32).shape == (32, 64, 3)


def test_envmap_from_exr_returns_at_once(tmp_path):
    # The EXR codec cannot poll: its thread runs on, the call returns (1.4 s to decode
    # 2048x1024 here when not interrupted; the signal lands in the decoding).
    path = tmp_path / "map.exr"
    vc.io.write_exr(path, np.random.default_rng(0).random((1024, 2048, 3), dtype=np.float32))
    interrupt(lambda: vc.EnvMap.from_exr(path, resolution=64), 0.05)
    assert vc.EnvMap.from_exr(path, resolution=16).resolution == 16


def test_slow_bvh_build_returns_at_once_and_keeps_the_scene():
    # 375k triangles: the "slow" builder takes 0.9 s on one thread, and runs on to its end
    # in the background once interrupted (it cannot stop part-way).
    setup = vc.scenes.load("hairball", detail=0.25)
    scene = setup.scene
    before = scene.bvh_stats()["quality"]
    interrupt(lambda: scene.build(quality="slow", threads=1), 0.2)
    assert scene.bvh_stats()["quality"] == before
    r = vc.render(setup, setup.camera.with_resolution(8, 6), spp=1, method="product",
                  progress=False)
    assert np.isfinite(r.image).all()


@pytest.fixture(scope="module")
def preview_setup(garage):
    cache = vc.VisibilityCache(garage.scene, preset="medium", resolution=32)
    cache.build(garage.camera.with_resolution(64, 48), progress=False)
    return cache


def test_preview_calls_stop(garage, preview_setup):
    cache = preview_setup
    cam = garage.camera.with_resolution(2048, 1536)
    # Tracing the G-buffer, then (from a traced one) the step after it: 0.2 s at 3M pixels.
    interrupt(lambda: vc.LightingPreview(garage.scene, cam), 0.1)
    g = garage.scene.gbuffer(cam)
    interrupt(lambda: vc.LightingPreview(garage.scene, gbuffer=g), 0.03)
    view = vc.LightingPreview(garage.scene, garage.camera.with_resolution(640, 480))
    interrupt(lambda: view.render(cache, garage.envmap, direct=True), 0.2)


@pytest.mark.parametrize("at", [0.02, 0.1, 0.3])
def test_prepare_stops_in_every_phase(garage, preview_setup, at):
    """Early in the call: its first phases (the points, the level, the map's cells, the
    measurements that choose the form of visibility and the basis) come before the
    transfer's build, 1.5 s in all; they polled nothing, and SIGINT 0.02 s in took 0.46 s."""
    cache = preview_setup
    view = vc.LightingPreview(garage.scene, garage.camera.with_resolution(320, 240))
    interrupt(lambda: view.prepare(cache, product_level=6), at)
    assert view.transfer_info is None
    small = vc.LightingPreview(garage.scene, garage.camera.with_resolution(16, 12))
    small.prepare(cache, basis="full")
    assert np.isfinite(small.render(cache, garage.envmap)).all()


def test_validate_and_converge_visibility_stop(garage, preview_setup):
    cache = preview_setup
    # About 1,100 records: 1.6 s of rays.
    interrupt(lambda: cache.validate(rays_per_record=16384), 0.3)
    assert cache.validate(rays_per_record=1)["rays"] > 0
    rl = vc.Relighter(garage, garage.camera.with_resolution(320, 240))
    # 64 samples take 2.2 s.
    interrupt(lambda: rl.converge_visibility(spp=4096, progress=False), 0.3)
    assert rl.converge_visibility(spp=1, progress=False)["spp"] == 1


FIRST_ARRAY = textwrap.dedent(
    """
    import os, signal, threading
    signal.signal(signal.SIGINT, signal.default_int_handler)
    import viscache_rs as vc
    e = vc.EnvMap.constant(1.0, resolution=256)
    threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT)).start()
    try:
        e.to_equirect(8192, 4096)
        print("finished")
    except KeyboardInterrupt:
        print("interrupted")
    """
)


def test_sigint_during_the_first_array_gives_keyboard_interrupt():
    """numpy's C API used to be loaded with the first array made, and a pending SIGINT
    then panicked inside it (PanicException, "Failed to access NumPy array API capsule")."""
    out = subprocess.run([sys.executable, "-c", FIRST_ARRAY], capture_output=True, text=True,
                         timeout=120)
    assert "PanicException" not in out.stderr, out.stderr
    assert out.stdout.strip() == "interrupted", out.stderr
