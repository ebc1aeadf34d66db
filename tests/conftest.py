"""Shared fixtures: generated meshes, the third-party meshes, and every mesh type."""

from __future__ import annotations

import os

# One OpenBLAS thread per pytest-xdist worker (set before numpy is first imported, which is here): the workers
# already fill the cores, and OpenBLAS's threads, spinning while they wait, crawl when the cores are oversubscribed
# (a 384 x 384 Cholesky factor 30 times slower with two workers of two threads each, or with another job beside).
# numba's threads (which the tests do check) are not touched; a serial run keeps OpenBLAS's own default.
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pytest

from meshdenoise.data import data_dir
from meshdenoise.io import load_arrays
from meshdenoise.shapes import grid, icosphere, torus

MESH_KINDS = ("arrays", "meshset", "pymeshlab_mesh", "open3d")


# Fixtures that load a third-party mesh: a test using one (directly, through another fixture, or by a
# parameter naming it for request.getfixturevalue) is marked ``data`` at collection, so
# ``pytest -m "not data"`` runs everything that needs no mesh. data_mesh_path() checks the mark.
DATA_FIXTURES = frozenset({"elephant", "nefertiti", "elephant_with_holes", "nefertiti_batch"})

_running = {"item": None}  # the test being set up or run (one per process, also under xdist)


def pytest_collection_modifyitems(items):
    for item in items:
        params = getattr(getattr(item, "callspec", None), "params", {})
        named = {v for v in params.values() if isinstance(v, str)}
        if DATA_FIXTURES.intersection(getattr(item, "fixturenames", ())) or DATA_FIXTURES.intersection(named):
            item.add_marker(pytest.mark.data)


def pytest_runtest_setup(item):
    _running["item"] = item


def pytest_runtest_teardown(item):
    _running["item"] = None


def data_mesh_path(name: str):
    """Path of a third-party mesh; skips with a reason on a clone without them, fails in CI.

    The calling test must carry the ``data`` marker (``@pytest.mark.data``, or a fixture of
    ``DATA_FIXTURES``), so that ``-m data`` / ``-m "not data"`` select exactly the tests needing the meshes.
    """
    item = _running["item"]
    if item is not None and item.get_closest_marker("data") is None:
        pytest.fail(f"{item.nodeid} reads {name} from the data folder: mark it @pytest.mark.data "
                    "(or add its fixture to DATA_FIXTURES in tests/conftest.py)")
    path = data_dir() / name
    if not path.is_file():
        reason = f"{name} not found in {data_dir()} (set MESHDENOISE_DATA to the folder of the paper's meshes)"
        if os.environ.get("MESHDENOISE_REQUIRE_DATA"):
            pytest.fail(reason + "; MESHDENOISE_REQUIRE_DATA is set, so this is an error")
        pytest.skip(reason)
    return path


@pytest.fixture(scope="session")
def elephant():
    return load_arrays(data_mesh_path("elephant-50kv.off"))


@pytest.fixture(scope="session")
def nefertiti():
    return load_arrays(data_mesh_path("nefertiti.off"))


@pytest.fixture(scope="session")
def elephant_with_holes(elephant):
    """The elephant with a few faces removed around four vertices: an open mesh with several boundary loops."""
    V, F = elephant
    drop = np.isin(F, [100, 5000, 12000, 20000]).any(axis=1)
    return V, F[~drop]


@pytest.fixture
def sphere():
    return icosphere(3)


@pytest.fixture
def plane():
    return grid(12, 9)


@pytest.fixture
def ring():
    return torus(20, 10)


def noisy_sphere(rho=0.02, seed=0, subdivisions=3):
    from meshdenoise import add_normal_noise

    V, F = icosphere(subdivisions)
    Vn, _ = add_normal_noise((V, F), rho=rho, seed=seed)
    return V, Vn, F


def make_mesh(kind: str, V: np.ndarray, F: np.ndarray, colors: np.ndarray | None = None, normals: bool = False):
    """Build a mesh of the given kind from arrays (vertex colours RGB in [0, 1] optional)."""
    if kind == "arrays":
        return (V.copy(), F.copy())
    if kind in ("meshset", "pymeshlab_mesh"):
        import pymeshlab

        kwargs = {}
        if colors is not None:
            kwargs["v_color_matrix"] = np.hstack([colors, np.ones((len(colors), 1))])
        m = pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32), **kwargs)
        if kind == "pymeshlab_mesh":
            return m
        ms = pymeshlab.MeshSet()
        ms.add_mesh(m, "input")
        return ms
    if kind == "open3d":
        import open3d as o3d

        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32)))
        if colors is not None:
            m.vertex_colors = o3d.utility.Vector3dVector(colors)
        if normals:
            m.compute_vertex_normals()
        return m
    raise ValueError(kind)


def vertices_of(mesh) -> np.ndarray:
    from meshdenoise.metrics import coordinates

    return coordinates(mesh)


@pytest.fixture(params=MESH_KINDS)
def mesh_kind(request):
    return request.param
