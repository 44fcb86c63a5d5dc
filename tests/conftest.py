"""Shared fixtures: a numpy brute-force ray tracer (the reference every answer is checked
against), random triangle soups and ray sets."""

from __future__ import annotations

import numpy as np
import pytest
import viscache_rs as vc

EDGE_TOLERANCE = 1e-5


def _bonferroni(tail, n: int, alpha: float, hi: float, steps: int) -> float:
    """The threshold where ``tail`` (a two-sided tail probability, falling) times ``n``
    equals ``alpha``, by bisection of ``[0, hi]``; at least 4."""
    lo = 0.0
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        if tail(mid) > alpha / n:
            lo = mid
        else:
            hi = mid
    return max(4.0, hi)


def bonferroni_z(n: int, alpha: float = 1e-3) -> float:
    """The z with P(|Z| > z) * n = alpha for a standard Gaussian (at least 4): the per-test
    threshold that keeps n independent comparisons' family-wise false alarms at alpha."""
    import math

    return _bonferroni(lambda z: math.erfc(z / math.sqrt(2)), n, alpha, 40.0, 200)


def student_t_bonferroni(n: int, dof: int, alpha: float = 1e-3) -> float:
    """:func:`bonferroni_z` for Student's t with ``dof`` degrees of freedom: the t with
    P(|T| > t) * n = alpha (at least 4), for means judged by their sample spread."""
    import math

    log_norm = (math.lgamma((dof + 1) / 2) - math.lgamma(dof / 2)
                - 0.5 * math.log(dof * math.pi))

    def tail(t: float) -> float:
        # Two-sided tail by Simpson's rule in u = 1/x over (0, 1/t]: the density's
        # x^-(dof+1) decay becomes a smooth u^(dof-1).
        steps, top = 2000, 1.0 / t
        h = top / steps

        def f(u: float) -> float:
            if u == 0.0:
                return 0.0
            x = 1.0 / u
            return math.exp(log_norm - (dof + 1) / 2 * math.log1p(x * x / dof)) / (u * u)

        total = f(0.0) + f(top) + sum((4 if k % 2 else 2) * f(k * h) for k in range(1, steps))
        return 2.0 * total * h / 3.0

    return _bonferroni(tail, n, alpha, 200.0, 100)


def brute_force(tris: np.ndarray, origins: np.ndarray, dirs: np.ndarray, tmax=np.inf,
                chunk: int = 128) -> dict[str, np.ndarray]:
    """Closest hits over all triangles in float64 (Moller-Trumbore, no BVH).

    Returns t (inf on miss), prim (-1 on miss); near_edge: whether the ray crosses any
    triangle's plane within EDGE_TOLERANCE (in barycentric units) of one of its edges, i.e.
    where float32 tracers may legitimately disagree on hit or miss; tie: whether another
    triangle is hit within EDGE_TOLERANCE (relative) of the closest distance (coincident
    surfaces), where the closest prim is not well defined; and t_tolerance: the absolute
    error float32 geometry allows on t (see t_tolerance()).
    """
    tris = np.asarray(tris, dtype=np.float64)
    o_all = np.asarray(origins, dtype=np.float64)
    d_all = np.asarray(dirs, dtype=np.float64)
    n = len(o_all)
    tmax_all = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,))
    v0, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    t_out = np.full(n, np.inf)
    prim_out = np.full(n, -1, dtype=np.int64)
    near = np.zeros(n, dtype=bool)
    tie = np.zeros(n, dtype=bool)
    t_tol = np.zeros(n)
    magnitude = np.abs(tris).max(axis=(1, 2))
    normals = np.cross(e1, e2)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    for s in range(0, n, chunk):
        o, d, tm = o_all[s:s + chunk, None, :], d_all[s:s + chunk, None, :], tmax_all[s:s + chunk]
        p = np.cross(d, e2[None])
        det = np.einsum("rmk,mk->rm", p, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            tv = o - v0[None]
            u = np.einsum("rmk,rmk->rm", tv, p) * inv
            q = np.cross(tv, e1[None])
            v = np.einsum("rmk,rk->rm", q, d[:, 0]) * inv
            t = np.einsum("rmk,mk->rm", q, e2) * inv
        w = 1.0 - u - v
        valid = (det != 0) & np.isfinite(t) & (t >= 0) & (t < tm[:, None])
        bary_min = np.minimum(np.minimum(u, v), w)
        hit = valid & (bary_min >= 0)
        near[s:s + chunk] = np.any(valid & (np.abs(bary_min) < EDGE_TOLERANCE), axis=1)
        tt = np.where(hit, t, np.inf)
        best = np.argmin(tt, axis=1)
        bt = tt[np.arange(len(best)), best]
        t_out[s:s + chunk] = bt
        prim_out[s:s + chunk] = np.where(np.isfinite(bt), best, -1)
        others = tt.copy()
        others[np.arange(len(best)), best] = np.inf
        tie[s:s + chunk] = np.isfinite(bt) & (others.min(axis=1) <= bt * (1 + EDGE_TOLERANCE))
        d_len = np.linalg.norm(d[:, 0], axis=1)
        cos = np.abs(np.einsum("rk,rk->r", normals[best], d[:, 0])) / d_len
        m = np.maximum(magnitude[best], np.abs(o[:, 0]).max(axis=1))
        t_tol[s:s + chunk] = t_tolerance(bt, m, cos) / d_len
    return {"t": t_out, "prim": prim_out, "near_edge": near, "tie": tie, "t_tolerance": t_tol}


def t_tolerance(t, magnitude, cos):
    """Allowed |t_float32 - t_exact| (distance units): 1e-5 relative, plus four float32
    ulps of the coordinates involved (vertices and origin, |coordinate| <= magnitude)
    amplified by 1/cos of the incidence angle. The second term is the representation limit
    of float32 geometry: a hit 0.5 m from an origin 100 m from the world's centre cannot be
    located better than ulp(100) / cos, whatever the tracer."""
    return 1e-5 * np.abs(t) + 4 * np.finfo(np.float32).eps * magnitude / np.maximum(cos, 1e-3)


def random_soup(rng: np.random.Generator, m: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """m random triangles of random size in the unit cube, as (vertices, faces)."""
    centers = rng.uniform(0, 1, (m, 1, 3))
    tris = centers + rng.normal(0, 0.08, (m, 3, 3))
    return tris.reshape(-1, 3).astype(np.float32), np.arange(3 * m).reshape(m, 3)


def random_rays(rng: np.random.Generator, n: int, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Origins uniform in the box [lo, hi], directions uniform on the sphere."""
    o = rng.uniform(lo, hi, (n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    return o, d


def scene_from_triangles(tris: np.ndarray) -> vc.Scene:
    s = vc.Scene()
    tris = np.asarray(tris, dtype=np.float32)
    s.add_mesh(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3))
    return s


@pytest.fixture(scope="session")
def cornell():
    return vc.scenes.load("cornell")


@pytest.fixture(scope="session")
def dynamics():
    return vc.scenes.load("dynamics")
