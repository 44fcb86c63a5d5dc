"""The six real meshes of the benchmark suite's ``meshes`` scene, fetched on first use.

They are Wavefront OBJ files of widely used test models from the public repository
alecjacobson/common-3d-test-models (``data/*.obj``), pinned to one commit and checked by
SHA-256, the way scientific Python packages ship sample data: the first
``vc.scenes.load("meshes")`` downloads them (about 2.1 MB) with pooch into the user's
cache folder (:func:`cache_dir`), and later calls read them from there.

A local folder takes precedence and needs no network: ``models_dir=`` where a function
takes it, else ``$VISCACHE_MODELS``, else ``../shared/models`` (from the current directory
or the source tree). Such a folder holds the files as ``NAME.obj.gz`` (gzipped) or
``NAME.obj``; :func:`local_dir` says which folder is used.

==============  =========  ===================================================
name            triangles  origin, as that repository lists it
==============  =========  ===================================================
teapot              6,320  Martin Newell's Utah teapot
spot                5,856  Keenan Crane's model repository (spot the cow)
cow                 5,804  Viewpoint Animation Engineering / Sun Microsystems
fandisk            12,946  CAD part (Pratt & Whitney, Hugues Hoppe)
rocker-arm         20,088  INRIA shape repository
homer              12,000  origin unclear (distributed with that repository)
==============  =========  ===================================================
"""

from __future__ import annotations

import gzip
import io
import os
from pathlib import Path

__all__ = ["BASE_URL", "COMMIT", "ENV", "NAMES", "REPOSITORY", "SHA256", "cache_dir", "fetch",
           "local_dir", "open_model", "url"]

#: The models, in the order the ``meshes`` scene arranges them.
NAMES = ("teapot", "spot", "cow", "fandisk", "rocker-arm", "homer")

#: The public repository the models come from.
REPOSITORY = "alecjacobson/common-3d-test-models"

#: The commit they are pinned to (its ``data/*.obj`` match :data:`SHA256`).
COMMIT = "8a4f8642acaf43f9cd7b67858a1502e1055ef202"

#: Where the files are downloaded from: ``BASE_URL + NAME + ".obj"``.
BASE_URL = f"https://raw.githubusercontent.com/{REPOSITORY}/{COMMIT}/data/"

#: The environment variable naming a local folder of the models.
ENV = "VISCACHE_MODELS"

#: SHA-256 of each uncompressed OBJ file.
SHA256 = {
    "teapot": "1b5396fedd74b577e32cef41146582c2f2e1a050d5b4915193c0ac1ad4187ed4",
    "spot": "0738b5e8608fed74e5e8c7aa8dd0af97b4b74f9f6cbf7aac84cd7e40b2e44a75",
    "cow": "69afce548640bc2beb0c44894d1a24d5766cc9cd3fd74f3ec55b4e229104b23f",
    "fandisk": "ea5bab2fbf545b1915f0d9faf6cc61ff8c18e0d8174ad61f8e35de15d8f6e3f8",
    "rocker-arm": "590257e6d01e689354821d807854306c3bfbb02d9cca73404d5a4924f105c287",
    "homer": "b20b1391fd62964f65703d748514d86d747d1202d38e55e0f1addac7a5a10e8b",
}


def url(name: str, base_url: str | None = None) -> str:
    """The address :func:`fetch` downloads model ``name`` from (``base_url``: default
    :data:`BASE_URL`)."""
    _check_name(name)
    return f"{BASE_URL if base_url is None else base_url}{name}.obj"


def _check_name(name: str) -> None:
    if name not in SHA256:
        raise ValueError(f"name: no model {name!r}; the models are {', '.join(NAMES)}")


def _has_models(folder: Path) -> bool:
    return all((folder / f"{n}.obj.gz").is_file() or (folder / f"{n}.obj").is_file()
               for n in NAMES)


def _local_candidates(path=None) -> list[Path]:
    if path is not None:
        return [Path(path)]
    candidates = []
    if os.environ.get(ENV):
        candidates.append(Path(os.environ[ENV]))
    candidates.append(Path.cwd() / ".." / "shared" / "models")
    candidates.append(Path(__file__).resolve().parents[3] / "shared" / "models")
    return candidates


def local_dir(path=None, required: bool = False) -> Path | None:
    """The local folder of the models: ``path`` if given, else ``$VISCACHE_MODELS``, else
    ``../shared/models`` from the current directory or from the package's source tree. A
    folder counts when it holds all six (``NAME.obj.gz`` or ``NAME.obj``). None when none
    does, or, with ``required``, FileNotFoundError naming every place looked at."""
    candidates = _local_candidates(path)
    for c in candidates:
        if _has_models(c):
            return c
    if required:
        raise FileNotFoundError(
            "models_dir: the real meshes (" + ", ".join(f"{n}.obj.gz" for n in NAMES)
            + ") are not in " + ", ".join(str(c) for c in candidates)
            + f"; pass models_dir= or set {ENV}")
    return None


def cache_dir() -> Path:
    """The user's cache folder the models are downloaded into (``~/.cache/viscache_rs/
    models`` on Linux; pooch's ``os_cache``, which honours ``$XDG_CACHE_HOME``)."""
    import pooch

    return Path(pooch.os_cache("viscache_rs")) / "models"


def _how_to_get(name: str, base_url: str) -> str:
    return (f"get the six files {', '.join(n + '.obj' for n in NAMES)} from "
            f"{base_url} (the repository {REPOSITORY}, commit {COMMIT}, folder data/) "
            f"into a folder, gzipped or not, and set {ENV} to that folder "
            "(or pass models_dir=)")


def fetch(name: str, cache: str | os.PathLike | None = None, base_url: str | None = None,
          progress: bool = False) -> Path:
    """The path of model ``name``'s OBJ file in the cache folder (``cache``, default
    :func:`cache_dir`), downloaded from ``base_url`` (default :data:`BASE_URL`) first if it
    is not there yet. The
    file's SHA-256 is checked against :data:`SHA256` after each download (a file already
    in the cache that does not match is downloaded again). Without network: OSError
    saying how to get the models by hand; a download whose hash does not match: ValueError
    (nothing is left in the cache)."""
    _check_name(name)
    import pooch

    folder = Path(cache) if cache is not None else cache_dir()
    base_url = BASE_URL if base_url is None else base_url
    source = url(name, base_url)
    try:
        return Path(pooch.retrieve(source, known_hash=f"sha256:{SHA256[name]}",
                                   fname=f"{name}.obj", path=folder, progressbar=progress))
    except ValueError as e:
        if "hash" not in str(e):
            raise
        raise ValueError(
            f"name: {name}.obj downloaded from {source} does not have the expected SHA-256 "
            f"({SHA256[name]}): the download was corrupted or the file changed; nothing was "
            f"kept. Try again, or {_how_to_get(name, base_url)}") from e
    except OSError as e:  # requests' errors (no network, HTTP 404) are OSErrors too
        raise OSError(
            f"name: could not download {name}.obj from {source} into {folder} "
            f"({type(e).__name__}: {e}). Without network, {_how_to_get(name, base_url)}"
        ) from e


def open_model(name: str, models_dir=None) -> io.BufferedIOBase:
    """Model ``name``'s OBJ file, opened for reading bytes: from the local folder
    (:func:`local_dir`, ``models_dir`` first) when there is one, else from the cache folder,
    downloading it on first use (:func:`fetch`). A ``models_dir`` given that does not hold
    the models is a FileNotFoundError (no download is tried)."""
    _check_name(name)
    folder = local_dir(models_dir, required=models_dir is not None)
    if folder is None:
        return open(fetch(name), "rb")
    if (folder / f"{name}.obj.gz").is_file():
        return gzip.GzipFile(folder / f"{name}.obj.gz", "rb")
    return open(folder / f"{name}.obj", "rb")
