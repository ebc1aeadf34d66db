"""Shared fixtures: generated meshes, the third-party meshes, and every mesh type."""

from __future__ import annotations

import os
import shutil
import tempfile

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


# A test without the ``data`` marker runs as on a clone without the meshes (CI's second pass): MESHDENOISE_DATA
# names an empty folder and MESHDENOISE_REQUIRE_DATA is unset, from before its fixtures are set up until after they
# are torn down (subprocesses inherit both). So a test that reads the data folder without the marker fails here, on
# the first pass, and the second pass need only run ``-m data`` (.ci/run); a skip naming that folder fails too
# (see data_skip_as_failure).
_DATA_VARS = ("MESHDENOISE_DATA", "MESHDENOISE_REQUIRE_DATA")
_no_data = {"folder": None, "saved": None}


def pytest_configure(config):
    _no_data["folder"] = tempfile.mkdtemp(prefix="meshdenoise-no-data-")


def pytest_unconfigure(config):
    if _no_data["folder"]:
        shutil.rmtree(_no_data["folder"], ignore_errors=True)


def no_data_folder() -> str:
    """The empty folder an unmarked test sees as MESHDENOISE_DATA."""
    return _no_data["folder"]


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    _running["item"] = item
    if item.get_closest_marker("data") is None:
        _no_data["saved"] = {k: os.environ.get(k) for k in _DATA_VARS}
        os.environ["MESHDENOISE_DATA"] = _no_data["folder"]
        os.environ.pop("MESHDENOISE_REQUIRE_DATA", None)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item, nextitem):  # a wrapper: the data variables come back after the fixtures' teardown
    try:
        return (yield)
    finally:
        _running["item"] = None
        saved, _no_data["saved"] = _no_data["saved"], None
        for k, v in (saved or {}).items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def data_skip_as_failure(marked: bool, skip_reason: str) -> str | None:
    """The failure message for an unmarked test that skipped because the data folder was empty, else None."""
    if marked or not _no_data["folder"] or _no_data["folder"] not in skip_reason:
        return None
    return (f"skipped for want of the data folder ({skip_reason.strip()}): a test that reads MESHDENOISE_DATA must be "
            "marked @pytest.mark.data (or use a fixture of DATA_FIXTURES in tests/conftest.py)")


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    if report.skipped and call.excinfo is not None:
        message = data_skip_as_failure(item.get_closest_marker("data") is not None, str(call.excinfo.value))
        if message:
            report.outcome, report.longrepr = "failed", f"{item.nodeid}: {message}"
    return report


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
