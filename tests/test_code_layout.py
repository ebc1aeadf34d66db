"""The code's floors: registration explicit, generic tuning machinery free of filters, caches bounded."""

from __future__ import annotations

import ast
import pkgutil
from pathlib import Path

import numpy as np
import pytest

import meshdenoise
from meshdenoise import plugins
from meshdenoise.cache import ByteLRU, clear_caches, nbytes
from meshdenoise.registry import AutoRule, Param, list_filters, register

PACKAGE = Path(meshdenoise.__file__).parent


def test_every_plugin_module_is_listed_explicitly():
    """A filter's module is listed in MODULES; its automatic rule's module, ``<filter>_rule``, sits next to it."""
    on_disk = {m.name for m in pkgutil.iter_modules(plugins.__path__) if not m.name.startswith("_")}
    rules = {name for name in on_disk if name.endswith("_rule")}
    assert on_disk - rules == set(plugins.MODULES)
    assert {name[: -len("_rule")] for name in rules} <= set(plugins.MODULES)


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            names.add("." * node.level + (node.module or ""))
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return names


@pytest.mark.parametrize("path", sorted((PACKAGE / "tuning").glob("*.py")), ids=lambda p: p.name)
def test_tuning_machinery_knows_no_filter(path):
    """Generic machinery below the plugins: no tuning module imports a plugin or names a filter's rule."""
    bad = {m for m in _imports(path) if "plugins" in m}
    assert not bad, f"{path.name} imports {bad}"
    assert "REGISTRY[" not in path.read_text()


def test_every_automatic_rule_is_declared_with_its_filter():
    with_rules = {s.name: s.auto for s in list_filters() if s.auto is not None}
    assert set(meshdenoise.auto_filters()) == set(with_rules)
    for name, rule in with_rules.items():
        spec = meshdenoise.get_filter(name)
        assert set(rule.tunes) <= {p.name for p in spec.params}
        # the rule lives in a module of its own next to the filter's (or, a short one, in the filter's module)
        assert rule.choose.__module__ in (spec.core.__module__ + "_rule", spec.core.__module__)


def test_register_refuses_a_rule_tuning_an_unknown_parameter():
    with pytest.raises(ValueError, match="AutoRule"):
        register("never_registered", params=[Param("k", int, 1)], summary="x", auto=AutoRule(("q",), lambda ctx: ({}, None)))
    for hooks, message in (({"border_draft": {"beta": 1.0}}, "border_draft= must be a function"),
                           ({"along_normals": True}, "along_normals= must be a function"),
                           ({"warm_start": "yes"}, "warm_start= must be True or False"),
                           ({"rough_free_run": 1}, "rough_free_run= must be True or False")):
        with pytest.raises(TypeError, match=message):
            register("never_registered", params=[Param("k", int, 1)], summary="x", **hooks)
    assert "never_registered" not in meshdenoise.registry.REGISTRY


def test_byte_lru_keeps_its_limit_and_the_newest_entry():
    c = ByteLRU(max_bytes=2000)
    for i in range(10):
        c.put(i, np.zeros(100))  # 800 B each
    assert list(c) == [8, 9] and c.total_bytes() == 1600
    big = c.put("big", np.zeros(1000))  # alone over the limit: kept, everything older goes
    assert list(c) == ["big"] and c.lookup("big") is big
    grow = c.put("list", [])
    grow.extend(np.zeros(300) for _ in range(2))  # grew in place after insertion
    c.trim()
    assert list(c) == ["list"]
    c.clear()
    assert len(c) == 0 and c.total_bytes() == 0


def test_nbytes_counts_sparse_matrices_and_not_views():
    import scipy.sparse as sp

    A = sp.random(50, 50, density=0.1, format="csr", random_state=0)
    assert nbytes(A) == A.data.nbytes + A.indices.nbytes + A.indptr.nbytes
    x = np.zeros(100)
    assert nbytes([x, x[:10]]) == 800


def test_operators_cache_is_bounded_in_bytes_and_cleared(monkeypatch):
    from meshdenoise import operators
    from meshdenoise.shapes import icosphere
    from meshdenoise.solvers import shifted_solver

    clear_caches()
    monkeypatch.setattr(operators, "CACHE_BYTES", 400_000)
    held = []
    for k in (2, 3):
        V, F = icosphere(k)
        ops = operators.get_operators(F, len(V))
        shifted_solver(ops, 1.0)  # a factor stored on the topology grows it
        held.append(ops)
    assert held[1].nbytes > 0 and operators._cache.total_bytes() <= max(400_000, held[1].nbytes)
    assert len(operators._cache) == 1  # the older topology was evicted when the newer grew
    assert held[0].cache  # ... but the caller's own object keeps its work
    clear_caches()
    assert len(operators._cache) == 0
    held[1].clear()
    assert held[1].cache == {} and held[1].L.shape == (len(icosphere(3)[0]),) * 2  # rebuilt lazily


def test_tuning_memo_is_bounded_and_cleared():
    from meshdenoise.tuning.memo import MEMO, MEMO_BYTES

    assert MEMO.max_bytes == MEMO_BYTES
    from meshdenoise.shapes import icosphere

    V, F = icosphere(2)
    Vn, _ = meshdenoise.add_normal_noise((V, F), rho=0.02, seed=0)
    meshdenoise.choose_parameters((Vn, F), "sobolev")
    assert len(MEMO) > 0 and MEMO.total_bytes() <= MEMO_BYTES
    clear_caches()
    assert len(MEMO) == 0


def test_nbytes_looks_inside_plain_objects():
    class Holder:
        def __init__(self):
            self.a = np.zeros(10)
            self.b = {"c": np.zeros(5)}

    assert nbytes(Holder()) == 120


def test_every_registered_filter_is_exported_at_the_top_level():
    for spec in meshdenoise.list_filters():
        assert getattr(meshdenoise, spec.name) is spec.public, spec.name
        assert spec.name in meshdenoise.__all__


def test_every_filter_docstring_says_how_to_choose_its_main_parameter_for_a_scan():
    # the advice is in mean edge lengths and points at the measured table it comes from
    from meshdenoise.registry import list_filters

    missing = [spec.name for spec in list_filters()
               if not ("for a scan" in (spec.public.__doc__ or "") and "mean edge lengths" in spec.public.__doc__
                       and "parameter-scale.md" in spec.public.__doc__)]
    assert missing == []


def test_denoise_and_the_denoise_step_empty_the_tuning_memo_before_their_filter(tmp_path, monkeypatch):
    """A choice's memo entries (255 MB at 1.6M vertices) must not sit beside the filter's buffers."""
    from click.testing import CliRunner

    from meshdenoise import registry
    from meshdenoise.cli import cli
    from meshdenoise.io import save_mesh
    from meshdenoise.shapes import icosphere
    from meshdenoise.tuning.memo import MEMO

    V, F = icosphere(2)
    Vn, _ = meshdenoise.add_normal_noise((V, F), rho=0.02, seed=0)
    seen = []
    run = registry._run_filter
    monkeypatch.setattr(registry, "_run_filter", lambda *a: (seen.append(len(MEMO)), run(*a))[1])
    clear_caches()
    meshdenoise.choose_parameters((Vn, F), "sobolev")
    assert len(MEMO) > 0  # the choice alone keeps its entries (a benchmark's oracle reuses them)
    meshdenoise.denoise((Vn, F), "sobolev")
    assert seen and seen[-1] == 0  # ... but denoise's filter starts with none (its choice runs the filter too)
    seen.clear()
    meshdenoise.denoise((Vn, F))  # the default: its choice, then its filter
    assert seen and seen[-1] == 0  # the filter, after the choice (which may run filters itself)
    save_mesh(tmp_path / "in.ply", Vn, F)
    for how in ([], ["--method", "heat"]):  # the denoise step's two ways: the default, a filter's own rule
        seen.clear()
        result = CliRunner().invoke(cli, ["denoise", *how, str(tmp_path / "in.ply"), str(tmp_path / "out.ply")])
        assert result.exit_code == 0, result.output
        assert seen and seen[-1] == 0  # the filter, after the choice (which may run filters itself)


def test_denoise_with_every_parameter_given_keeps_the_tuning_memo():
    """No choice in the call, nothing released: a caller's earlier search stays reusable."""
    from meshdenoise.shapes import icosphere
    from meshdenoise.tuning.memo import MEMO

    V, F = icosphere(2)
    Vn, _ = meshdenoise.add_normal_noise((V, F), rho=0.02, seed=0)
    clear_caches()
    mu = meshdenoise.choose_parameters((Vn, F), "sobolev")["mu"]
    kept = set(MEMO)
    assert kept
    meshdenoise.denoise((Vn, F), "sobolev", mu=mu)
    assert set(MEMO) == kept
