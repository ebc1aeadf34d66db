"""The parts of ``two_stage``: face neighbourhoods, bilateral and guided normal passes, the vertex fit.

Each works on arrays (faces, unit normals, areas, centroids) through the compiled loops of
:mod:`meshdenoise.kernels`; :mod:`meshdenoise.plugins.two_stage` chains them into the filter.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .operators import Operators

__all__ = ["FaceNeighbourhood", "face_neighbourhood", "bilateral_normals", "guidance_normals", "fit_vertices_to_normals",
           "two_stage_topology", "power_of_two_scale"]


class FaceNeighbourhood:
    """Faces sharing a vertex with each face (itself included), as CSR rows; cached per topology.

    Built by compiled loops (:mod:`meshdenoise.kernels`) in time linear in the number of
    face pairs, without forming ``M^T M``. The edge pairs and the patches' edge lists serve
    the guided filter only: they are built on first use (the bilateral filter, the default's,
    never builds them: at 5M vertices they took 10 of the 17 s and about 100 bytes per vertex).

    Attributes
    ----------
    m : int
        Number of faces.
    indptr : ndarray of int64, shape (m + 1,)
    indices : ndarray of int32, shape (nnz,)
        Row ``f`` (``indices[indptr[f]:indptr[f + 1]]``, sorted) lists the faces ``g``
        sharing at least one vertex with ``f``; every row holds ``f`` itself.
    edge_a, edge_b : ndarray of int32 (int64 from 2^31 faces), shape (E,)
        Pairs of faces sharing an edge: consecutive face sides of the same undirected
        edge in (edge key, corner) order, so each pair of a manifold edge once.
    label : ndarray of int64, shape (m,)
        Each face's index in the caller's order (``label`` given: these faces are a
        relabelling of the caller's); patch ties and the pairing of the sides of an edge
        follow it. The identity by default.
    patch_ptr : ndarray of int64, shape (m + 1,)
    patch_edge : ndarray of int32
        For the guided filter: row ``j`` lists, increasing, the edge pairs ``e`` whose two
        faces both lie in the neighbourhood (patch) of face ``j``.
    """

    def __init__(self, F: np.ndarray, n: int, label: np.ndarray | None = None):
        from . import kernels

        kernels.set_threads()
        self._F, self._n = F, int(n)  # the caller's faces (not copied), read again for the edge pairs
        m = F.shape[0]
        self.m = m
        # ties between patches go to the least label: the face's index in the caller's order
        # (an int64 label is kept, not copied: the caller's face_order)
        self._relabelled = label is not None
        self.label = np.arange(m, dtype=np.int64) if label is None else np.require(label, dtype=np.int64, requirements=["C"])
        self.indptr, self.indices = kernels.face_neighbour_lists(F, n)
        self._edges: tuple[np.ndarray, np.ndarray] | None = None
        self._patches: tuple[np.ndarray, np.ndarray] | None = None

    def _edge_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        from . import kernels

        if self._edges is None:
            F, m, n = self._F, self.m, self._n
            # faces sharing an edge: consecutive face sides of the same undirected edge, sides in the
            # caller's face order (which pairs an edge of 3 or more sides makes depends on it)
            if self._relabelled:
                Fc = np.empty((m, 3), dtype=np.int64)
                Fc[self.label] = F
                a, b = kernels.edge_side_pairs(Fc, n)
                del Fc
                back = np.empty(m, dtype=np.int64)
                back[self.label] = np.arange(m)
                a, b = back[a], back[b]
            else:
                a, b = kernels.edge_side_pairs(np.require(F, dtype=np.int64, requirements=["C"]), n)
            edge_dtype = np.int32 if m < 2**31 - 1 else np.int64
            self._edges = (a.astype(edge_dtype), b.astype(edge_dtype))
        return self._edges

    @property
    def edge_a(self) -> np.ndarray:
        return self._edge_pairs()[0]

    @property
    def edge_b(self) -> np.ndarray:
        return self._edge_pairs()[1]

    def _patch_lists(self) -> tuple[np.ndarray, np.ndarray]:
        from . import kernels

        if self._patches is None:
            self._patches = kernels.patch_edge_lists(self.indptr, self.indices, self.edge_a, self.edge_b)
        return self._patches

    @property
    def patch_ptr(self) -> np.ndarray:
        return self._patch_lists()[0]

    @property
    def patch_edge(self) -> np.ndarray:
        return self._patch_lists()[1]

    @property
    def nbytes(self) -> int:
        """Bytes held by the arrays built so far (the caller's faces not counted)."""
        arrays = [self.indptr, self.indices, self.label, *(self._edges or ()), *(self._patches or ())]
        return sum(a.nbytes for a in arrays)

    @property
    def starts(self) -> np.ndarray:
        """Index where each face's row begins, shape (m,)."""
        return self.indptr[:-1]

    @property
    def rows(self) -> np.ndarray:
        """Row (face) of every pair, shape (nnz,), int64: with :attr:`cols`, the pairs sorted by (f, g)."""
        return np.repeat(np.arange(self.m), np.diff(self.indptr))

    @property
    def cols(self) -> np.ndarray:
        """Column (neighbour face) of every pair, shape (nnz,), int64."""
        return self.indices.astype(np.int64)

    def matrix(self, weights: np.ndarray) -> sp.csr_matrix:
        """The (m, m) CSR matrix with ``weights`` (nnz,) on the pairs."""
        return sp.csr_matrix((weights, self.indices, self.indptr), shape=(self.m, self.m))


def face_neighbourhood(ops: Operators) -> FaceNeighbourhood:
    """The cached :class:`FaceNeighbourhood` of this topology."""
    if "face_neighbourhood" not in ops.cache:
        ops.cache["face_neighbourhood"] = FaceNeighbourhood(ops.F, ops.n)
    return ops.cache["face_neighbourhood"]


def _float_rows(X: np.ndarray) -> np.ndarray:
    """A writable C-contiguous float64 copy: the kernels are compiled for that one array type."""
    return np.array(X, dtype=np.float64, order="C")


QUANTUM = 1e9  # patch scores are compared on a grid of this many steps of their range: equal within it, a tie


def _quantisation(H: np.ndarray) -> float:
    """The factor that maps ``H`` to integers on a :data:`QUANTUM` grid of its range (0 when ``H`` is all zero).

    Symmetric meshes have patches of equal scores whose computed values differ by rounding: on the
    grid they are ties, broken by the faces' labels in the caller's order. A quantised choice cannot
    be continuous: a score within rounding of a step's edge can fall either way. A translation of
    the mesh changes the rounding (6e-12 of the scores at 1000 times the extent): hypothesis found a
    face subset of ``icosphere(2)`` moved by 1024 whose result moved by 0.145 that way. A coarser grid
    (1e6) fixes that mesh but makes near-ties ties, broken by the labels: a shuffled mesh then gives
    results 2e-8 apart (tests/test_locality.py). Hence 1e9 (docs/peers.md).
    """
    scale = float(H.max()) if H.size else 0.0
    return QUANTUM / scale if scale > 0 else 0.0


def _label_bits(m: int) -> int:
    """Bits that hold every face label below ``m`` beside a quantised score (at most 2^30, :data:`QUANTUM`) in an int64."""
    bits = max(1, int(m - 1).bit_length())
    if bits > 33:
        raise ValueError(f"two_stage: {m:,} faces, more than the guided filter's 2^33")
    return bits


class GuidanceBuffers:
    """Scratch arrays of the guided filter, (m, 3), two (m,) and (E,), allocated once per run.

    ``g`` (the patch means, (m, 3)) is needed only inside :meth:`guidance`: a caller may set it
    to an (m, 3) array of its own that is dead at that time (the next pass's output) instead.
    """

    def __init__(self, nb: FaceNeighbourhood, g: np.ndarray | None = None):
        self.g = np.empty((nb.m, 3)) if g is None else g
        self.H = np.empty(nb.m)
        self.key = np.empty(nb.m, dtype=np.int64)  # pick_guidance's packed (score, label)
        self.phi = np.empty(nb.edge_a.size)

    def guidance(self, N: np.ndarray, areas: np.ndarray, nb: FaceNeighbourhood, out: np.ndarray) -> np.ndarray:
        from . import kernels

        kernels.patch_scores(N, areas, nb.indptr, nb.indices, nb.edge_a, nb.edge_b, nb.patch_ptr, nb.patch_edge,
                             self.g, self.H, self.phi)
        kernels.pick_guidance(self.H, _quantisation(self.H), self.g, nb.indptr, nb.indices, nb.label,
                              _label_bits(nb.m), self.key, out)
        return out


def guidance_normals(N: np.ndarray, areas: np.ndarray, nb: FaceNeighbourhood) -> np.ndarray:
    """Zhang et al. (2015) guidance: the mean normal of the most consistent patch containing each face.

    The patch of face j is its neighbourhood P_j. Its mean normal is
    :math:`g_j = \\mathrm{unit}(\\sum_{k \\in P_j} A_k n_k)` and its inconsistency
    :math:`H(P_j) = D(P_j) R(P_j)`, with :math:`D = \\max_{k \\in P_j} \\|n_k - g_j\\|`
    (the normal spread; the paper uses the largest pairwise difference) and
    :math:`R = \\max_e \\varphi_e / (\\epsilon + \\sum_e \\varphi_e)` over the
    edges inside the patch, :math:`\\varphi_e = \\|n_a - n_b\\|`. A patch on one side
    of a sharp edge has a small H. Face i takes :math:`g_j` of the patch
    :math:`P_j \\ni i` with the smallest H.

    Symmetric meshes (an icosahedron, a CAD part's flat sides) have exactly tied patches;
    rounding noise (say from a translation) must not decide between them, so H is
    quantised to 1e-9 of its range and near-ties are ties, broken by patch index.

    Parameters
    ----------
    N : ndarray, shape (m, 3)
        Unit face normals.
    areas : ndarray, shape (m,)
    nb : FaceNeighbourhood

    Returns
    -------
    ndarray, shape (m, 3)
    """
    from . import kernels

    kernels.set_threads()
    N, areas = _float_rows(N), _float_rows(areas)
    return GuidanceBuffers(nb).guidance(N, areas, nb, np.empty((nb.m, 3)))


def bilateral_normals(
    N: np.ndarray,
    centroids: np.ndarray,
    areas: np.ndarray,
    nb: FaceNeighbourhood,
    *,
    sigma_s: float,
    sigma_r: float,
    iterations: int,
    guided: bool,
) -> np.ndarray:
    """``iterations`` Jacobi passes of (guided) bilateral filtering of the unit face normals ``N`` (m, 3).

    .. math:: n_i \\leftarrow \\mathrm{unit}\\Big(\\sum_{j \\in \\mathcal N(i)} A_j\\,
              e^{-\\|c_i - c_j\\|^2 / 2\\sigma_s^2}\\, e^{-\\|g_i - g_j\\|^2 / 2\\sigma_r^2}\\, n_j\\Big)

    with :math:`g = n` (bilateral, Zheng et al. 2011) or the guidance normals of
    :func:`guidance_normals` recomputed every pass (guided, Zhang et al. 2015).
    ``centroids`` (m, 3), ``areas`` (m,); ``sigma_s`` in the centroids' units. Each pass
    is two compiled loops over the face pairs (guidance, then the weighted sum).
    """
    from . import kernels

    kernels.set_threads()
    N = np.array(N, dtype=np.float64, order="C")
    centroids, areas = _float_rows(centroids), _float_rows(areas)
    S = np.empty(nb.indices.size)
    kernels.spatial_weights(centroids, areas, nb.indptr, nb.indices, 2.0 * sigma_s**2, S)
    return bilateral_passes(N, areas, nb, S, sigma_r, iterations, guided)


def bilateral_passes(N, areas, nb, S, sigma_r, iterations, guided, out=None, G=None, buffers=None):
    """The passes of :func:`bilateral_normals` on spatial weights ``S``; ``N`` is overwritten (returns the result).

    Scratch: ``out`` and ``G`` (m, 3) and the guided filter's ``buffers``, allocated here when
    not given. The result is ``N`` or ``out``. The patch means ``g`` live in the ``out`` of
    each pass (dead until the pass writes it), so a guided pass needs three (m, 3) arrays.
    """
    from . import kernels

    if iterations == 0:
        return N
    out = np.empty_like(N) if out is None else out
    if guided:
        buffers = GuidanceBuffers(nb, g=out) if buffers is None else buffers
        G = np.empty_like(N) if G is None else G
    denom = 2.0 * sigma_r**2
    for _ in range(iterations):
        if guided:
            buffers.g = out  # dead until bilateral_pass writes it below
            buffers.guidance(N, areas, nb, G)
        else:
            G = N
        kernels.bilateral_pass(N, G, S, nb.indptr, nb.indices, denom, out)
        N, out = out, N
    return N


def _corner_lists(F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex, its corner indices ``3 f + k`` in increasing order, as CSR (int64 pointers).

    A counting sort (:func:`meshdenoise.kernels.topology._csr_of_groups`): the same arrays as a stable
    argsort of the corners' vertices, in one pass (the argsort took 0.4 s at 1.6M vertices).
    """
    from .kernels.topology import _csr_of_groups

    corner_vertex = F.ravel()
    dtype = np.int32 if corner_vertex.size < 2**31 - 1 else np.int64
    return _csr_of_groups(corner_vertex, n, dtype)


def fit_scale(corner_ptr: np.ndarray, pinned: np.ndarray | None) -> np.ndarray:
    count = np.diff(corner_ptr).astype(np.float64)
    scale = np.zeros(count.size)
    np.divide(1.0, count, out=scale, where=count > 0)
    if pinned is not None:
        scale[pinned] = 0.0
    return scale


def fit_vertices_to_normals(
    X: np.ndarray, F: np.ndarray, N: np.ndarray, iterations: int, pinned: np.ndarray | None = None
) -> np.ndarray:
    """Move vertices so that the faces become orthogonal to the target normals ``N`` (Sun et al. 2007).

    .. math:: x_i \\leftarrow x_i + \\frac{1}{|F_i|} \\sum_{f \\ni i} n_f\\, \\big(n_f \\cdot (c_f - x_i)\\big)

    ``iterations`` Jacobi steps; :math:`c_f` is the face centroid under the current
    positions; :math:`F_i` the faces around vertex i. Fixed and isolated vertices stay.
    ``X`` (n, 3), ``F`` (m, 3), ``N`` (m, 3); returns a new (n, 3) array.
    """
    from . import kernels

    kernels.set_threads()
    X = np.array(X, dtype=np.float64, order="C")
    F = np.array(F, dtype=np.int64, order="C")
    ptr, corners = _corner_lists(F, X.shape[0])
    kernels.fit_vertices(X, F, _float_rows(N), ptr, corners, fit_scale(ptr, pinned), int(iterations), np.empty((F.shape[0], 3)))
    return X


class _TwoStageTopology:
    """Everything ``two_stage`` needs of a topology, on relabelled vertices and faces (cached in ``ops``).

    Vertices in :attr:`Operators.locality_order` (reverse Cuthill-McKee), faces sorted by
    their first relabelled corner: neighbouring faces and vertices sit close in memory,
    which made a normal-filtering pass 1.7 times faster on the subdivided elephant. Only
    the order of the (commutative) sums changes, and ties between patches still go to
    the least face index of the caller's order.

    Faces already in that order (a mesh :mod:`meshdenoise.locality` relabelled: vertices in
    locality order, faces sorted by their least corner) are taken as they are: the
    relabelling, the sort and the faces' labels would all be the identity.
    """

    def __init__(self, ops: Operators):
        n, m = ops.n, ops.F.shape[0]
        self.vertex_order = ops.locality_order
        # int32 faces when the vertex count allows (half of int64's bytes; the kernels take either)
        index = np.int32 if n < 2**31 - 1 else np.int64
        if ops.in_locality_order:  # the identity order: the faces keep their labels
            F = ops.F.astype(index)
        else:
            rank = np.empty(n, dtype=index)
            rank[self.vertex_order] = np.arange(n)
            F = rank[ops.F]
            del rank
        first = F.min(axis=1)
        if m < 2 or bool(np.all(first[1:] >= first[:-1])):  # already sorted: a stable sort keeps the order
            self.F, label = np.ascontiguousarray(F), None
        else:
            order = np.argsort(first, kind="stable")
            self.F, label = np.ascontiguousarray(F[order]), order
        del F, first
        self.nb = FaceNeighbourhood(self.F, n, label=label)
        self.face_order = self.nb.label  # faces' indices in the caller's order (the identity when not sorted)
        self.corner_ptr, self.corners = _corner_lists(self.F, n)

    @property
    def nbytes(self) -> int:
        arrays = (self.vertex_order, self.F, self.corner_ptr, self.corners)
        return self.nb.nbytes + sum(a.nbytes for a in arrays)  # face_order is nb.label, counted there


def two_stage_topology(ops: Operators) -> _TwoStageTopology:
    if "two_stage_topology" not in ops.cache:
        ops.cache["two_stage_topology"] = _TwoStageTopology(ops)
    return ops.cache["two_stage_topology"]


def power_of_two_scale(X: np.ndarray) -> int:
    """The exponent ``k`` with ``2^k`` near the extent of ``X``: dividing by it is exact and makes the extent ~1."""
    if X.size == 0:
        return 0
    extent = float(np.max(X.max(axis=0) - X.min(axis=0)))
    if not np.isfinite(extent) or extent <= 0.0:
        return 0
    return int(np.frexp(extent)[1])
