"""Compiled (numba) kernels of the nonlinear filters: two-stage normal filtering, Open3D-weight Taubin, the
products and recurrences of the linear solvers and spectral filters.

The linear filters are sparse products (:func:`meshdenoise.operators.spmm`); the nonlinear
ones recompute their weights from the current coordinates at every pass, which in numpy
means arrays of one value per face pair or per edge (tens of millions at scan size) and a
sort per pass. Here each pass is one loop over faces (or vertices) in CSR order, threaded
with numba's ``prange`` over rows, writing into preallocated buffers: no per-pass
allocation, no sort, no Python loop over elements.

Every kernel sums in the same order as the numpy/scipy code it replaces (CSR rows in
index order, products ``a * x`` added to a zero start), so results agree with it to a few
units in the last place, and computes each output element on one thread in a fixed order,
so results do not depend on the thread count. Compiled code is cached on disk
(``cache=True``, in this package's ``__pycache__``): the first call in a fresh install
compiles (a few seconds), later processes load it. Where numba finds no writable place (a
read-only install with a read-only HOME) the cache moves to a private temporary folder, or
is left out (:mod:`.threads`); importing never fails for it.

Index arrays: ``indptr`` int64, ``indices`` int32 (int64 above 2^31 entries).

Modules: :mod:`.threads` (numba's set-up, the cache's place, thread counts and limits),
:mod:`.elementary` (unit vectors, the exponential, cross products, inlined into the others),
:mod:`.geometry` (face normals, areas, centroids; normal turns), :mod:`.bilateral` (normal
filtering over face pairs and its guidance), :mod:`.sparse` (CSR products, conjugate-gradient
steps), :mod:`.lanczos` (the spectral filters' recurrences), :mod:`.vertices` (vertex passes),
:mod:`.topology` (neighbourhoods of a face list) and :mod:`.walk` (a tuning walk's sums).
Every name is importable from ``meshdenoise.kernels`` itself.
"""

from __future__ import annotations

from numba import prange  # noqa: F401 - the kernels' loop, named here for modules that write their own kernels

from .threads import (  # noqa: F401
    _limits,
    CACHE,
    compiled_here,
    CONCURRENT_BELOW,
    every_thread,
    njit,
    run_concurrently,
    set_threads,
    single_threaded,
    spmm_threads,
    thread_limit,
)
from .elementary import (  # noqa: F401
    _as_double,
    EXP_BLOCK,
    EXP_FLOOR,
    EXP_LN2_HI,
    EXP_LN2_LO,
    EXP_LOG2E,
    exp_nonpositive,
    exp_one,
    EXP_SHIFT,
    face_cross,
    unit_into,
)
from .geometry import (  # noqa: F401
    face_geometry,
    normal_turns,
    normal_turns_adjoint_many,
    normal_turns_many,
)
from .bilateral import (  # noqa: F401
    _block_pairs,
    bilateral_pass,
    bilateral_spatial_pass,
    centroid_spacing_sums,
    EXP_CHUNK,
    gaussian_block,
    PAIR_MATH,
    patch_scores,
    pick_guidance,
    spatial_weights,
)
from .sparse import (  # noqa: F401
    add_row_product,
    CG_BLOCK,
    cg_direction,
    cg_product,
    cg_step,
    csr_matmat,
    csr_matmat3,
)
from .lanczos import (  # noqa: F401
    lanczos_accumulate,
    lanczos_accumulate_steps,
    lanczos_next,
    lanczos_next_row,
    lanczos_product,
    lanczos_regenerate,
    lanczos_scale,
    lanczos_update,
    shifted_tridiagonal_solves,
)
from .vertices import (  # noqa: F401
    corner_face,
    face_corner_mean,
    fit_vertices,
    inverse_distance_pass,
    projected_divergence_terms,
    restore_tangential,
)
from .topology import (  # noqa: F401
    _consecutive_pairs,
    _counting_sort,
    _csr_of_groups,
    _merge3,
    _merge3_count,
    _merge3_fill,
    _patch_edges,
    _sort_rows,
    edge_side_pairs,
    face_neighbour_lists,
    patch_edge_lists,
)
from .walk import (  # noqa: F401
    _curve_partials,
    CURVE_CHUNK,
    curve_terms,
)

import numba  # noqa: E402,F401 - configured by .threads (its threading layer), named here for other kernels' modules

__all__ = [
    "CACHE",
    "compiled_here",
    "CONCURRENT_BELOW",
    "every_thread",
    "njit",
    "run_concurrently",
    "set_threads",
    "single_threaded",
    "spmm_threads",
    "thread_limit",
    "EXP_BLOCK",
    "EXP_FLOOR",
    "EXP_LN2_HI",
    "EXP_LN2_LO",
    "EXP_LOG2E",
    "exp_nonpositive",
    "exp_one",
    "EXP_SHIFT",
    "face_cross",
    "unit_into",
    "face_geometry",
    "normal_turns",
    "normal_turns_adjoint_many",
    "normal_turns_many",
    "bilateral_pass",
    "bilateral_spatial_pass",
    "centroid_spacing_sums",
    "EXP_CHUNK",
    "gaussian_block",
    "PAIR_MATH",
    "patch_scores",
    "pick_guidance",
    "spatial_weights",
    "add_row_product",
    "CG_BLOCK",
    "cg_direction",
    "cg_product",
    "cg_step",
    "csr_matmat",
    "csr_matmat3",
    "lanczos_accumulate",
    "lanczos_accumulate_steps",
    "lanczos_next",
    "lanczos_next_row",
    "lanczos_product",
    "lanczos_regenerate",
    "lanczos_scale",
    "lanczos_update",
    "shifted_tridiagonal_solves",
    "corner_face",
    "face_corner_mean",
    "fit_vertices",
    "inverse_distance_pass",
    "projected_divergence_terms",
    "restore_tangential",
    "edge_side_pairs",
    "face_neighbour_lists",
    "patch_edge_lists",
    "CURVE_CHUNK",
    "curve_terms",
]
