"""two_stage's run holds its buffers and no copy beyond them (peak memory per vertex)."""

from __future__ import annotations

import tracemalloc

import meshdenoise as md
from meshdenoise.operators import get_operators
from meshdenoise.normal_filter import two_stage_topology as _two_stage_topology
from meshdenoise.registry import get_filter
from meshdenoise.shapes import icosphere


def test_a_two_stage_run_allocates_its_buffers_and_not_more_than_one_extra_vertex_array():
    V, F = icosphere(5)
    Vn = md.add_normal_noise((V, F), 0.01, seed=0)[0]
    ops = get_operators(F, len(V))
    spec = get_filter("two_stage")
    values = spec.resolve({"iterations": 2, "keep_tangential": True})
    spec.core(Vn, F, ops=ops, pinned=None, **values)  # the topology is cached: the run's own memory is measured
    topo = _two_stage_topology(ops)
    n, m, nnz, E = len(V), len(F), topo.nb.indices.size, topo.nb.edge_a.size
    # S (nnz); N, areas, C, out (10 m); the guided filter's phi (E) and packed keys (m); X, Y and the result (3 of (n, 3))
    buffers = 8 * (nnz + 11 * m + E + 3 * 3 * n)
    tracemalloc.start()
    try:
        spec.core(Vn, F, ops=ops, pinned=None, **values)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # small (n,) arrays fit in one (n, 3) array's bytes; a copy of the input or of the result (2.6 of them)
    # does not
    assert buffers <= peak <= buffers + 8 * 3 * n, (peak, buffers)
