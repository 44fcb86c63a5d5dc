"""The real meshes of the ``meshes`` scene (``viscache_rs.models``): pinned addresses,
SHA-256 checks, the user's cache folder, a local folder's precedence and the errors without
network. Downloads are exercised against an HTTP server on localhost: the suite never
reaches the internet, and the real files are used only where a local copy exists."""

from __future__ import annotations

import functools
import gzip
import hashlib
import http.server
import socket
import threading
from pathlib import Path

import numpy as np
import pytest
import viscache_rs as vc
from viscache_rs import models

TETRA = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


@pytest.fixture
def server(tmp_path):
    """An HTTP server on localhost serving ``tmp_path/served``; yields (that folder, the
    base URL of its ``data/``, the list of paths requested)."""
    root = tmp_path / "served"
    (root / "data").mkdir(parents=True)
    requested: list[str] = []

    class Handler(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

        def do_GET(self):
            requested.append(self.path)
            super().do_GET()

    httpd = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(Handler, directory=str(root)))
    thread = threading.Thread(target=httpd.serve_forever, args=(0.05,), daemon=True)
    thread.start()
    try:
        yield root / "data", f"http://127.0.0.1:{httpd.server_address[1]}/data/", requested
    finally:
        httpd.shutdown()
        httpd.server_close()
        thread.join(timeout=5)


def closed_port_url() -> str:
    """A localhost URL nothing listens on: downloads fail as they do without network."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"http://127.0.0.1:{port}/data/"


@pytest.fixture
def no_local_folder(monkeypatch):
    """No local folder of the models, as on a user's machine."""
    monkeypatch.delenv(models.ENV, raising=False)
    monkeypatch.setattr(models, "_local_candidates",
                        lambda path=None: [Path(path)] if path is not None else [])


def test_the_models_are_pinned_to_a_commit_and_their_hashes():
    assert models.NAMES == vc.scenes.MODEL_NAMES and set(models.SHA256) == set(models.NAMES)
    assert models.url("teapot") == (
        "https://raw.githubusercontent.com/alecjacobson/common-3d-test-models/"
        "8a4f8642acaf43f9cd7b67858a1502e1055ef202/data/teapot.obj")
    with pytest.raises(ValueError, match="^name: no model 'bunny'"):
        models.url("bunny")
    folder = models.local_dir()
    if folder is None:
        pytest.skip("no local copy of the models to check the pinned hashes against")
    for name in models.NAMES:
        with models.open_model(name) as f:
            assert hashlib.sha256(f.read()).hexdigest() == models.SHA256[name], name


def test_fetch_downloads_once_into_the_cache_and_checks_the_hash(server, tmp_path,
                                                                  monkeypatch):
    served, base, requested = server
    (served / "teapot.obj").write_bytes(TETRA)
    monkeypatch.setitem(models.SHA256, "teapot", hashlib.sha256(TETRA).hexdigest())
    cache = tmp_path / "cache"
    path = models.fetch("teapot", cache=cache, base_url=base)
    assert path == cache / "teapot.obj" and path.read_bytes() == TETRA
    assert requested == ["/data/teapot.obj"]
    assert models.fetch("teapot", cache=cache, base_url=base) == path
    assert len(requested) == 1, "the second call reads the cache"
    # A cached file that no longer matches is downloaded again.
    path.write_bytes(b"damaged")
    assert models.fetch("teapot", cache=cache, base_url=base).read_bytes() == TETRA
    assert len(requested) == 2


def test_a_corrupt_download_fails_its_hash_check_and_is_not_kept(server, tmp_path,
                                                                  monkeypatch):
    served, base, _ = server
    monkeypatch.setitem(models.SHA256, "cow", hashlib.sha256(TETRA).hexdigest())
    (served / "cow.obj").write_bytes(TETRA.replace(b"v 0 0 1", b"v 0 0 2"))
    cache = tmp_path / "cache"
    with pytest.raises(ValueError, match="^name: cow.obj downloaded from http://127.0.0.1") as e:
        models.fetch("cow", cache=cache, base_url=base)
    assert "SHA-256" in str(e.value) and models.ENV in str(e.value)
    assert not (cache / "cow.obj").exists()
    assert not [p for p in cache.rglob("*") if p.is_file()], "no partial file is left"


def test_without_network_the_error_says_how_to_get_the_models(server, tmp_path,
                                                              no_local_folder, monkeypatch):
    base = closed_port_url()
    with pytest.raises(OSError, match="^name: could not download teapot.obj") as e:
        models.fetch("teapot", cache=tmp_path / "cache", base_url=base)
    assert base in str(e.value) and models.ENV in str(e.value)
    # A file the server does not have (404) is the same error.
    _, served_base, _ = server
    with pytest.raises(OSError, match="could not download spot.obj"):
        models.fetch("spot", cache=tmp_path / "cache", base_url=served_base)
    # What a user sees: the scene names the address and the variable.
    monkeypatch.setattr(models, "BASE_URL", base)
    monkeypatch.setattr(models, "cache_dir", lambda: tmp_path / "user-cache")
    with pytest.raises(OSError) as e:
        vc.scenes.load("meshes")
    assert f"{base}teapot.obj" in str(e.value) and models.ENV in str(e.value)


def test_a_local_folder_takes_precedence(tmp_path, server, monkeypatch):
    _, base, requested = server
    monkeypatch.setattr(models, "BASE_URL", base)
    folder = tmp_path / "mine"
    folder.mkdir()
    for k, name in enumerate(models.NAMES):
        data = TETRA.replace(b"v 0 0 1", f"v 0 0 {k + 1}".encode())
        if k % 2:
            (folder / f"{name}.obj").write_bytes(data)
        else:
            (folder / f"{name}.obj.gz").write_bytes(gzip.compress(data))
    monkeypatch.setenv(models.ENV, str(folder))
    assert models.local_dir() == folder and vc.scenes.models_dir() == folder
    setup = vc.scenes.load("meshes")
    assert setup.scene.object_names() == ["ground", *models.NAMES]
    assert setup.scene.num_triangles == 2 * 40 * 40 + 4 * len(models.NAMES)
    assert requested == [], "nothing is downloaded when a local folder has the models"
    # An explicit folder without them is an error, not a download.
    with pytest.raises(FileNotFoundError, match="^models_dir:"):
        vc.scenes.meshes(tmp_path / "empty")


def test_the_meshes_scene_downloads_the_real_models(server, tmp_path, no_local_folder,
                                                    monkeypatch):
    local = models.local_dir(Path(__file__).resolve().parents[2] / "shared" / "models")
    if local is None:
        local = models.local_dir(Path.cwd() / ".." / "shared" / "models")
    if local is None:
        pytest.skip("no local copy of the real models to serve")
    served, base, requested = server
    for name in models.NAMES:
        (served / f"{name}.obj").write_bytes(gzip.decompress((local / f"{name}.obj.gz")
                                                             .read_bytes()))
    monkeypatch.setattr(models, "BASE_URL", base)
    monkeypatch.setattr(models, "cache_dir", lambda: tmp_path / "user-cache")
    fetched = vc.scenes.load("meshes")
    assert sorted(requested) == sorted(f"/data/{n}.obj" for n in models.NAMES)
    assert sorted(p.name for p in (tmp_path / "user-cache").iterdir()) == sorted(
        f"{n}.obj" for n in models.NAMES)
    from_folder = vc.scenes.meshes(local)
    np.testing.assert_array_equal(fetched.scene.triangles(), from_folder.scene.triangles())
    assert fetched.scene.num_triangles == 66_214
