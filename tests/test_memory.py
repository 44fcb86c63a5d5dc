"""Buffers sized by the caller are allocated fallibly: under an address-space limit a size
that cannot be met raises MemoryError naming what was being allocated, and the process
goes on (it used to die of SIGABRT from Rust's allocation-failure handler).

Each case runs in a child process whose address space is limited (``RLIMIT_AS``) to what
it already maps plus ``HEADROOM``, set after its inputs exist; its sizes need more than
that, so the allocation fails at once rather than after seconds of work."""

import subprocess
import sys
import textwrap

import pytest

resource = pytest.importorskip("resource")

HEADROOM = 1 << 30

PRELUDE = f"""
import resource, sys
import numpy as np
import viscache_rs as vc
import viscache_rs.analysis


def limit():
    # What the process maps now (thread stacks, numpy, the inputs) plus the headroom.
    with open("/proc/self/status") as f:
        size = next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmSize:"))
    resource.setrlimit(resource.RLIMIT_AS, (size + {HEADROOM}, size + {HEADROOM}))


def expect_memory_error(call, what):
    try:
        call()
    except MemoryError as e:
        assert str(e).startswith(what + ":"), str(e)
        assert "GiB" in str(e), str(e)
        print("MemoryError:", e)
        sys.exit(0)
    sys.exit("no MemoryError")
"""

CASES = {
    "to_equirect": """
        env = vc.EnvMap.constant(1.0, resolution=64)
        limit()
        expect_memory_error(lambda: env.to_equirect(32768, 16384), "to_equirect")
    """,
    "from_equirect": """
        rgb = np.ones((4096, 8192, 3), "f4")
        limit()
        expect_memory_error(lambda: vc.EnvMap.from_equirect(rgb, 64), "rgb")
    """,
    "from_equirect_resolution": """
        rgb = np.ones((8, 16, 3), "f4")
        limit()
        expect_memory_error(lambda: vc.EnvMap.from_equirect(rgb, 4096), "resolution")
    """,
    "camera_rays": """
        cam = vc.Camera.look_at((0, 0, 5), (0, 0, 0), width=16384, height=16384)
        limit()
        expect_memory_error(cam.rays, "rays")
    """,
    "write_exr": """
        import os, tempfile
        image = np.zeros((6144, 8192, 3), "f4")
        path = os.path.join(tempfile.mkdtemp(), "big.exr")
        limit()
        expect_memory_error(lambda: vc.io.write_exr(path, image), "image")
    """,
    "visibility_maps": """
        s = vc.Scene()
        s.add_mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
        n = 600_000
        p = np.zeros((n, 3), "f4") + [0.2, 0.2, 1.0]
        nrm = np.tile(np.array([0, 0, 1], "f4"), (n, 1))
        limit()
        call = lambda: vc.analysis.visibility_maps(s, p, nrm, resolution=128)
        expect_memory_error(call, "points")
    """,
    "bvh_build": """
        s = vc.Scene()
        n = 4_000_000
        rng = np.random.default_rng(0)
        s.add_mesh(rng.random((3 * n, 3), dtype="f4"), np.arange(3 * n).reshape(n, 3))
        limit()
        expect_memory_error(s.build, "scene")
    """,
    "add_mesh": """
        s = vc.Scene()
        # 36 bytes of triangle and 4 of object id per face, beyond the headroom.
        faces = np.zeros((40_000_000, 3), "i8")
        limit()
        verts = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
        try:
            s.add_mesh(verts, faces)
        except MemoryError:
            # Nothing half-added.
            assert s.num_triangles == 0, s.num_triangles
        expect_memory_error(lambda: s.add_mesh(verts, faces), "faces")
    """,
    "scene_load": """
        limit()
        expect_memory_error(lambda: vc.scenes.load("hairball", detail=16), "detail")
    """,
    "preview_prepare": """
        setup = vc.scenes.load("cornell", detail=0.25)
        cam = setup.camera.with_resolution(128, 96)
        cache = vc.VisibilityCache(setup.scene, preset="low")
        cache.build(cam, progress=False)
        view = vc.LightingPreview(setup.scene, cam)
        limit()
        # The full basis at level 8: 256 KiB a pixel.
        call = lambda: view.prepare(cache, setup.envmap, basis="full", product_level=8,
                                    budget_mb=1e6)
        expect_memory_error(call, "budget_mb")
    """,
    "render_unbuilt": """
        s = vc.Scene()
        n = 4_000_000
        rng = np.random.default_rng(0)
        s.add_mesh(rng.random((3 * n, 3), dtype="f4"), np.arange(3 * n).reshape(n, 3))
        cam = vc.Camera.look_at((0.5, 0.5, 3), (0.5, 0.5, 0), width=8, height=8)
        env = vc.EnvMap.constant(1.0, resolution=8)
        limit()
        call = lambda: vc.render(vc.scenes.Setup(s, cam, env), spp=1, method="env",
                                 progress=False)
        expect_memory_error(call, "scene")
    """,
}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
@pytest.mark.parametrize("case", sorted(CASES))
def test_too_large_a_buffer_is_a_memory_error_not_an_abort(case):
    code = PRELUDE + textwrap.dedent(CASES[case])
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, (p.returncode, p.stdout, p.stderr[-2000:])
    assert "MemoryError:" in p.stdout
