"""Notebooks and logs: progress bars stay out of logs unless asked for."""

from __future__ import annotations

import io
import sys

import pytest
import viscache_rs as vc
from viscache_rs._progress import progress_bar, wants_bar


@pytest.fixture(scope="module")
def cornell():
    return vc.scenes.load("cornell")


# ---- progress bars -------------------------------------------------------------------------


class _Terminal(io.StringIO):
    """A stderr that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def test_progress_default_draws_no_bar_when_stderr_is_not_a_terminal(cornell, capfd):
    cam = cornell.camera.with_resolution(12, 9)
    assert not sys.stderr.isatty()  # pytest captures it
    vc.render(cornell, camera=cam, spp=2)
    relighter = vc.Relighter(cornell, camera=cam)
    relighter.converge_visibility(spp=32)
    err = capfd.readouterr().err
    assert "render (mis)" not in err and "visibility" not in err, err
    # Asked for, the bar is drawn all the same.
    relighter.converge_visibility(spp=32, progress=True)
    vc.render(cornell, camera=cam, spp=2, progress=True)
    err = capfd.readouterr().err
    assert "visibility" in err and "render (mis)" in err, err


def test_progress_default_draws_a_bar_on_a_terminal(cornell, monkeypatch):
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    cam = cornell.camera.with_resolution(12, 9)
    vc.render(cornell, camera=cam, spp=2)
    assert "render (mis)" in terminal.getvalue()
    terminal.truncate(0)
    vc.render(cornell, camera=cam, spp=2, progress=False)
    assert terminal.getvalue() == ""


def test_wants_bar_follows_tqdms_disable_none(monkeypatch):
    assert wants_bar(True) and not wants_bar(False)
    monkeypatch.setattr(sys, "stderr", _Terminal())
    assert wants_bar(None)
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    assert not wants_bar(None)
    monkeypatch.setattr(sys, "stderr", None)  # pythonw: no stderr at all
    assert not wants_bar(None)
    with progress_bar(None, "x", "px") as callback:
        assert callback is None
