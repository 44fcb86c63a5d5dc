"""Progress bars are drawn in Python from the core's reports: the cache build reports
through a callback like the renderer, AO and the visibility maps."""

from __future__ import annotations

import viscache_rs as vc
from viscache_rs._progress import progress_bar


def test_the_cache_build_reports_to_a_callback_and_stops_when_told():
    s = vc.scenes.load("cornell")
    cam = s.camera.with_resolution(24, 18)
    seen: list[tuple[int, int]] = []

    def record(done: int, total: int) -> bool:
        seen.append((done, total))
        return True

    cache = vc.VisibilityCache(s.scene, preset="medium")
    report = cache.build(cam, callback=record)
    assert report["complete"] and seen
    assert all(0 <= d <= t for d, t in seen)
    assert seen[-1][0] == seen[-1][1]
    # The same build without a callback, with and without a bar, gives the same records.
    for progress in (True, False):
        again = vc.VisibilityCache(s.scene, preset="medium")
        assert again.build(cam, progress=progress)["records"] == report["records"]
    stopped = vc.VisibilityCache(s.scene, preset="medium")
    assert not stopped.build(cam, callback=lambda done, total: False)["complete"]


def test_the_bar_is_drawn_in_python(capfd):
    s = vc.scenes.load("cornell")
    vc.VisibilityCache(s.scene).build(s.camera.with_resolution(8, 6), progress=True)
    assert "cache build" in capfd.readouterr().err
    vc.VisibilityCache(s.scene).build(s.camera.with_resolution(8, 6), progress=False)
    assert "cache build" not in capfd.readouterr().err


def test_a_loaded_cache_is_the_package_class(tmp_path):
    s = vc.scenes.load("cornell")
    cam = s.camera.with_resolution(8, 6)
    cache = vc.VisibilityCache(s.scene, preset="medium", resolution=16)
    cache.build(cam, progress=False)
    cache.save(tmp_path / "c.vcache")
    again = vc.VisibilityCache.load(tmp_path / "c.vcache", s.scene)
    assert type(again) is vc.VisibilityCache
    assert len(again) == len(cache) and again.resolution == 16
    assert again.params == cache.params
    again.build(cam, progress=False)


def test_progress_bar_helper():
    with progress_bar(False, "x", "px") as callback:
        assert callback is None
    with progress_bar(True, "x", "spp", total=4, per_unit=10) as callback:
        assert callback is not None
        assert callback(20, 40) is True
