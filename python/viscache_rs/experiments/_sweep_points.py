"""A sweep's points: what one point may say, its defaults, and sweep files (JSON or TOML).

A point is one render measured against its scene's reference: a dict with the keys of
:data:`POINT_KEYS`. Every point is checked whole before any work, and a bad one is a
ValueError or TypeError naming the point (``points[i]``), the key and, for a file, the
file: a sweep never starts on input it would refuse half-way.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from .. import _core, scenes

#: A point's keys and what each means (the sweep file's documentation, README "Sweeps").
POINT_KEYS: dict[str, str] = {
    "scene": "a built-in scene name (vc.scenes.names()); required",
    "method": "a vc.render method (vc.methods()); required",
    "spp": "samples per pixel (at most that many under a time_budget)",
    "time_budget": "seconds for the render; spp or time_budget or both is required",
    "seed": "the render's seed (default 0); the row is a function of it",
    "params": "further keyword arguments of vc.render (alpha, jitter, technique_weights, ...)",
    "cache": "a VisibilityCache for the point: {preset, resolution, seed, ...overrides}; "
             "built once per scene, size and settings and shared by the points that name it",
    "width": "image width in pixels (default 64)",
    "height": "image height in pixels (default 48)",
    "detail": "the scene's detail (default 1)",
    "scene_seed": "the seed the scene is made with (vc.scenes.load's; default 0)",
    "label": "the row's name for the configuration (default: the method)",
    "reference": "{method, spp, seed} of the reference image, or false for none (default "
                 "product, 1024 spp, seed 104729); rendered once per scene and size",
    "repeats": "renders of the point whose least time is reported (default 1; same image)",
    "image": "true: the row carries the rendered image (column 'image'; default false)",
}

#: The reference of a point that names none: product sampling, many samples, a seed apart
#: from the points' own (an image and its reference must be independent for relMSE's
#: subtraction of the reference's variance, ``vc.metrics.relmse``).
DEFAULT_REFERENCE: dict[str, Any] = {"method": "product", "spp": 1024, "seed": 104729}
REFERENCE_KEYS = ("method", "spp", "seed")
DEFAULT_WIDTH, DEFAULT_HEIGHT = 64, 48

# Render arguments a point sets through its own keys (or that are objects, not values).
_OWN = {"camera", "spp", "seed", "threads", "progress", "time_budget", "gbuffer", "cache",
        "envmap", "vpls"}
_FILE_KEYS = ("points", "defaults")


def _methods() -> dict[str, dict[str, Any]]:
    return {m["name"]: m for m in _core.methods()}


def _where(index: int, source: str | None) -> str:
    return f"{source}: points[{index}]" if source else f"points[{index}]"


def _integer(value: Any, what: str, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{what}: expected an integer, got {value!r}")
    if value < low:
        raise ValueError(f"{what}: must be at least {low}, got {value}")
    return value


def _cache_keys() -> set[str]:
    # The native class's own parameter names; a throwaway cache of an empty scene lists them.
    return set(_core.VisibilityCache(_core.Scene()).params) | {"preset", "seed"}


def check_point(point: Any, index: int = 0, source: str | None = None,
                defaults: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """``point`` (over ``defaults``) checked and completed with every default: a new dict
    with all of :data:`POINT_KEYS`. Raises ValueError/TypeError naming ``source`` (a file),
    ``points[index]`` and the key."""
    where = _where(index, source)
    if not isinstance(point, Mapping):
        raise TypeError(f"{where}: expected a table of keys, got {type(point).__name__}")
    merged = {**(defaults or {}), **point}
    for key in merged:
        if key not in POINT_KEYS:
            raise ValueError(f"{where}: unknown key {key!r}; expected one of "
                             f"{', '.join(POINT_KEYS)}")
    for key in ("scene", "method"):
        if key not in merged:
            raise ValueError(f"{where}: {key!r} is required")
    scene, method = merged["scene"], merged["method"]
    if scene not in scenes.names():
        raise ValueError(f"{where}.scene: unknown scene {scene!r}; expected one of "
                         f"{', '.join(scenes.names())}")
    methods = _methods()
    if method not in methods:
        raise ValueError(f"{where}.method: unknown method {method!r}; expected one of "
                         f"{', '.join(methods)}")
    row = methods[method]
    out: dict[str, Any] = {"scene": scene, "method": method}
    if merged.get("spp") is None and merged.get("time_budget") is None:
        raise ValueError(f"{where}: give 'spp' or 'time_budget' (or both)")
    out["spp"] = (None if merged.get("spp") is None
                  else _integer(merged["spp"], f"{where}.spp", 1))
    budget = merged.get("time_budget")
    if budget is not None:
        if isinstance(budget, bool) or not isinstance(budget, int | float):
            raise TypeError(f"{where}.time_budget: expected seconds, got {budget!r}")
        if not (math.isfinite(budget) and budget > 0):
            raise ValueError(f"{where}.time_budget: must be positive, got {budget!r}")
        budget = float(budget)
    out["time_budget"] = budget
    out["seed"] = _integer(merged.get("seed", 0), f"{where}.seed", 0)
    low, high = _core.LIMITS["image_side"]
    for key, default in (("width", DEFAULT_WIDTH), ("height", DEFAULT_HEIGHT)):
        out[key] = _integer(merged.get(key, default), f"{where}.{key}", max(low, 1))
        if out[key] > high:
            raise ValueError(f"{where}.{key}: must be at most {high}, got {out[key]}")
    detail = merged.get("detail", 1.0)
    if isinstance(detail, bool) or not isinstance(detail, int | float) or not detail > 0:
        raise ValueError(f"{where}.detail: expected a positive number, got {detail!r}")
    out["detail"] = float(detail)
    out["scene_seed"] = _integer(merged.get("scene_seed", 0), f"{where}.scene_seed", 0)
    params = merged.get("params") or {}
    if not isinstance(params, Mapping):
        raise TypeError(f"{where}.params: expected a table, got {type(params).__name__}")
    allowed = (set(row["params"]) | set(row["common"])) - _OWN
    for key in params:
        if key not in allowed:
            raise ValueError(f"{where}.params: unknown key {key!r} for method {method!r}; "
                             f"expected one of {', '.join(sorted(allowed))}")
    out["params"] = dict(params)
    cache = merged.get("cache")
    if cache is not None:
        if "VisibilityCache" not in row["caches"]:
            raise ValueError(f"{where}.cache: method {method!r} takes no VisibilityCache")
        if not isinstance(cache, Mapping):
            raise TypeError(f"{where}.cache: expected a table, got {type(cache).__name__}")
        known = _cache_keys()
        for key in cache:
            if key not in known:
                raise ValueError(f"{where}.cache: unknown key {key!r}; expected one of "
                                 f"{', '.join(sorted(known))}")
        cache = {"seed": 0, **cache}
        _integer(cache["seed"], f"{where}.cache.seed", 0)
    out["cache"] = None if cache is None else dict(cache)
    label = merged.get("label", method)
    if not isinstance(label, str):
        raise TypeError(f"{where}.label: expected text, got {label!r}")
    out["label"] = label
    reference = merged.get("reference", DEFAULT_REFERENCE)
    if reference is False or reference is None:
        out["reference"] = None
    else:
        if not isinstance(reference, Mapping):
            raise TypeError(f"{where}.reference: expected a table or false, got {reference!r}")
        for key in reference:
            if key not in REFERENCE_KEYS:
                raise ValueError(f"{where}.reference: unknown key {key!r}; expected one of "
                                 f"{', '.join(REFERENCE_KEYS)}")
        ref = {**DEFAULT_REFERENCE, **reference}
        if ref["method"] not in methods:
            raise ValueError(f"{where}.reference.method: unknown method {ref['method']!r}")
        _integer(ref["spp"], f"{where}.reference.spp", 1)
        _integer(ref["seed"], f"{where}.reference.seed", 0)
        out["reference"] = ref
    out["repeats"] = _integer(merged.get("repeats", 1), f"{where}.repeats", 1)
    image = merged.get("image", False)
    if not isinstance(image, bool):
        raise TypeError(f"{where}.image: expected true or false, got {image!r}")
    out["image"] = image
    return out


def check_points(points: Iterable[Any], source: str | None = None,
                 defaults: Mapping[str, Any] | None = None) -> list[dict[str, Any]]:
    """Every point checked (:func:`check_point`); at least one."""
    if isinstance(points, Mapping | str | bytes):
        raise TypeError(f"{source or 'points'}: expected a list of points, got "
                        f"{type(points).__name__}")
    out = [check_point(p, i, source, defaults) for i, p in enumerate(points)]
    if not out:
        raise ValueError(f"{source or 'points'}: the sweep has no points")
    return out


def load(path: str | Path) -> list[dict[str, Any]]:
    """The points of a sweep file, checked: JSON (a list of points, or an object with
    ``points`` and optional ``defaults``) or TOML (``[defaults]`` and ``[[points]]``).
    ``defaults`` gives keys every point takes unless it sets its own. Any other key, in the
    file or a point, is a ValueError naming it and the file."""
    path = Path(path)
    source = str(path)
    try:
        text = path.read_bytes()
    except OSError as e:
        raise ValueError(f"{source}: cannot read the sweep file ({e.strerror})") from None
    try:
        if path.suffix.lower() == ".toml":
            data: Any = tomllib.loads(text.decode())
        elif path.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            raise ValueError(f"{source}: expected a .json or .toml sweep file")
    except (tomllib.TOMLDecodeError, json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{source}: not a valid {path.suffix[1:].upper()} file: {e}") from None
    if isinstance(data, list):
        return check_points(data, source)
    if not isinstance(data, dict):
        raise ValueError(f"{source}: expected a list of points or a table with 'points'")
    for key in data:
        if key not in _FILE_KEYS:
            raise ValueError(f"{source}: unknown key {key!r}; expected one of "
                             f"{', '.join(_FILE_KEYS)}")
    defaults = data.get("defaults") or {}
    if not isinstance(defaults, dict):
        raise TypeError(f"{source}: defaults: expected a table")
    for key in defaults:
        if key not in POINT_KEYS:
            raise ValueError(f"{source}: defaults: unknown key {key!r}; expected one of "
                             f"{', '.join(POINT_KEYS)}")
    if "points" not in data:
        raise ValueError(f"{source}: 'points' is required")
    return check_points(data["points"], source, defaults)
