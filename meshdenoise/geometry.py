"""Per-face and per-vertex geometry on the array core: normals, areas, volume, cotangent Laplacian.

Three vertex normals, each for a reason: :func:`vertex_normals` (the paper's, unit face
normals averaged), :func:`area_normals` (area-weighted: collapsed faces get no vote) and
:func:`coherent_normals` (shortened where the faces around a vertex disagree).

All functions take ``V (n, 3) float64`` and ``F (m, 3) int`` and are vectorised.
A zero-area face has a zero normal (not NaN) and contributes nothing to vertex normals.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp

from .kernels import face_cross, njit, prange, set_threads, unit_into

__all__ = [
    "cross_rows",
    "face_normals",
    "face_areas",
    "vertex_normals",
    "numpy_vertex_normals",
    "area_normals",
    "coherent_normals",
    "coherent_normals_derivative",
    "signed_volume",
    "cotangent_laplacian",
    "lumped_mass",
]


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of ``a`` and ``b`` (m, 3), shape (m, 3): ``np.cross(a, b)`` bit for bit, faster.

    The same products and differences in the same order as numpy's (so the same rounding),
    written per component: ``np.cross`` on (3.2M, 3) rows took 2.1 s, this 0.37 s (the 1.6M
    scale mesh's faces, loaded machine).

    Examples
    --------
    >>> import numpy as np
    >>> cross_rows(np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]])).tolist()
    [[0.0, 0.0, 1.0]]
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3 or b.shape != a.shape:
        raise ValueError(f"cross_rows: a and b must both have shape (m, 3), got {a.shape} and {b.shape}")
    out = np.empty_like(a)
    for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):
        np.multiply(a[:, i], b[:, j], out=out[:, k])
        out[:, k] -= a[:, j] * b[:, i]
    return out


def _cross(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    if F.shape[0] >= KERNEL_MIN_FACES:
        V, F = _kernel_arrays(V, F, "_cross")
        set_threads()
        out = np.empty((F.shape[0], 3))
        _face_cross_rows(V, F, out)
        return out
    P0 = V[F[:, 0]]
    return cross_rows(V[F[:, 1]] - P0, V[F[:, 2]] - P0)


#: From this many faces :func:`face_normals` and the cross products behind :func:`face_areas` and
#: :func:`area_normals` run a compiled kernel (the same numbers): numpy's way makes five (m, 3)
#: temporaries (120 bytes per face) and took 0.24 s per call on the 400k-vertex elephant under load,
#: the kernel none and about 10 ms; below it, loading the compiled code (once per process) would cost more.
KERNEL_MIN_FACES = 1 << 16


def _kernel_arrays(V: np.ndarray, F: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``V`` float64 and ``F`` int64, both C-contiguous, the indices checked: the compiled code reads ``V[F]`` unchecked."""
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F)
    if F.dtype != np.int64 and F.dtype != np.int32:
        F = F.astype(np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"{name}: V must be (n, 3) and F (m, 3), got {V.shape} and {F.shape}")
    if F.size and (F.min() < 0 or F.max() >= V.shape[0]):
        raise IndexError(f"{name}: face indices must lie in 0 .. {V.shape[0] - 1}, got {F.min()} .. {F.max()}")
    return V, F


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _face_cross_rows(V, F, out):  # pragma: no cover - compiled
    """``out[f] = cross(V[b] - V[a], V[c] - V[a])``: numpy's arithmetic (no fused multiply-add), the same bits."""
    for f in prange(F.shape[0]):
        c0, c1, c2 = face_cross(V, F[f, 0], F[f, 1], F[f, 2])
        out[f, 0] = c0
        out[f, 1] = c1
        out[f, 2] = c2


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _face_unit_normals(V, F, out):  # pragma: no cover - compiled
    """``out[f]`` = the cross product divided by :math:`\\sqrt{(x^2 + y^2) + z^2}` (numpy's row norm), zero if that is 0."""
    for f in prange(F.shape[0]):
        c0, c1, c2 = face_cross(V, F[f, 0], F[f, 1], F[f, 2])
        unit_into(out, f, c0, c1, c2)


def _normalize_rows(X: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(X, axis=1, keepdims=True)
    out = np.zeros_like(X)
    np.divide(X, norms, out=out, where=norms > 0)
    return out


def _scatter_faces_to_vertices(values: np.ndarray, F: np.ndarray, n: int) -> np.ndarray:
    """Sum a per-face quantity (m,) or (m, k) onto the three vertices of each face."""
    idx = F.T.ravel()
    if values.ndim == 1:
        return np.bincount(idx, weights=np.tile(values, 3), minlength=n)
    return np.stack(
        [np.bincount(idx, weights=np.tile(values[:, d], 3), minlength=n) for d in range(values.shape[1])],
        axis=1,
    )


def vertex_face_incidence(F: np.ndarray, n: int) -> sp.csr_matrix:
    """The (n, m) 0/1 matrix with a 1 where vertex ``i`` is a corner of face ``f``: ``M @ values`` sums faces onto vertices.

    Built as its transpose's CSR (face ``f``'s row holds its three corners), turned into CSR by scipy's
    counting pass: 12 bytes per corner in all (int32 indices when they fit) against 48 through COO. Each row's
    faces are in increasing order, as before; a degenerate face's repeated corner is one entry of 2.

    Examples
    --------
    >>> import numpy as np
    >>> vertex_face_incidence(np.array([[0, 1, 2], [0, 2, 3]]), 4).toarray()
    array([[1., 1.],
           [1., 0.],
           [1., 1.],
           [0., 1.]])
    """
    F = np.asarray(F)
    m = F.shape[0]
    index = np.int32 if max(n, 3 * m) < 2**31 - 1 else np.int64
    T = sp.csr_matrix((np.ones(3 * m), F.astype(index).ravel(), np.arange(0, 3 * m + 1, 3, dtype=index)), shape=(m, n))
    M = T.T.tocsr()  # the transpose of a CSR is the CSC of M: converting it sorts each vertex's faces
    del T
    if m and ((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])).any():
        M.sum_duplicates()
    return M


def face_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Triangle areas, shape (m,).

    Examples
    --------
    >>> import numpy as np
    >>> face_areas(np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    array([0.5])
    """
    return 0.5 * np.linalg.norm(_cross(V, F), axis=1)


def face_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Unit face normals (right-hand rule), shape (m, 3); zero for zero-area faces.

    Examples
    --------
    >>> import numpy as np
    >>> face_normals(np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    array([[0., 0., 1.]])

    From :data:`KERNEL_MIN_FACES` faces a compiled kernel computes the same numbers without temporaries.
    """
    if np.shape(F)[0] >= KERNEL_MIN_FACES:
        V, F = _kernel_arrays(V, F, "face_normals")
        set_threads()
        out = np.empty((F.shape[0], 3))
        _face_unit_normals(V, F, out)
        return out
    return _normalize_rows(_cross(V, F))


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Vertex normals as in the paper: the normalised sum of the unit normals of the faces around each vertex.

    .. math:: N_i = \\frac{\\sum_{f \\ni i} n_f}{\\|\\sum_{f \\ni i} n_f\\|}

    Each face counts once per vertex, whatever its area. A vertex on no face, or whose
    face normals cancel, gets a zero normal.

    Returns
    -------
    ndarray, shape (n, 3)

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]])
    >>> vertex_normals(V, np.array([[0, 1, 2]]))[[0, 3]]
    array([[0., 0., 1.],
           [0., 0., 0.]])

    From 65,536 vertices the compiled kernel
    :func:`meshdenoise.tuning.noise_kernels.vertex_normals` computes the same numbers, bit for
    bit, without nine ``(m,)`` temporaries (0.7 -> 0.1 s at 1.6M vertices);
    :func:`numpy_vertex_normals` is the numpy computation at every size. That module sits above
    this one and registers its kernel here when imported (:data:`LARGE_VERTEX_NORMALS`).
    """
    for compiled in LARGE_VERTEX_NORMALS:
        N = compiled(V, F)
        if N is not None:
            return N
    return numpy_vertex_normals(V, F)


# (V, F) -> the normals, or None when the mesh is too small for it: meshdenoise.tuning.noise_kernels (above this module,
# loaded with the package) appends its compiled kernel at import
LARGE_VERTEX_NORMALS: list[Callable[[np.ndarray, np.ndarray], np.ndarray | None]] = []


def numpy_vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """:func:`vertex_normals` by numpy at every size: the reference the compiled kernel is tested against."""
    return _normalize_rows(_scatter_faces_to_vertices(face_normals(V, F), F, V.shape[0]))


def area_normals(X: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals :math:`n_i \\propto \\sum_{f \\ni i} (x_b - x_a) \\times (x_c - x_a)`, shape (n, 3).

    A degenerate (collapsed) face of a strongly smoothed mesh has a cross product near
    zero and so no vote, whereas its unit normal (:func:`vertex_normals`)
    is rounding noise. A vertex whose faces all vanish gets a zero normal.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 1e-20]])
    >>> area_normals(V, np.array([[0, 1, 2], [1, 3, 2]]))[0].tolist()
    [0.0, 0.0, 1.0]
    """
    return _normalize_rows(_scatter_faces_to_vertices(_cross(X, F), F, X.shape[0]))


def coherent_normals(X: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Vertex normals shortened where the faces around a vertex disagree.

    .. math:: s_i = \\sum_{f \\ni i} n_f, \\qquad N_i = \\frac{s_i}{\\max(\\|s_i\\|, k_i / 2)}

    with :math:`k_i` the number of faces at vertex ``i``: the paper's unit vertex normal
    where the unit face normals roughly agree (:math:`\\|s_i\\| \\ge k_i/2`), shrinking
    continuously to 0 where they cancel (a folded, over-smoothed patch), whose direction
    would otherwise be set by rounding. ``|N_i| <= 1``, so :math:`W_i \\succeq I`.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]])
    >>> coherent_normals(V, np.array([[0, 1, 2], [0, 2, 1]]))[0]  # two opposite faces cancel
    array([0., 0., 0.])
    """
    n = X.shape[0]
    s = _scatter_faces_to_vertices(face_normals(X, F), F, n)
    k = np.bincount(F.ravel(), minlength=n).astype(np.float64)
    norm = np.maximum(np.linalg.norm(s, axis=1), 0.5 * k)
    return np.divide(s, norm[:, None], out=np.zeros_like(s), where=norm[:, None] > 0)


def coherent_normals_derivative(X: np.ndarray, F: np.ndarray, Y: np.ndarray, chunk: int = 256) -> np.ndarray:
    """Directional derivatives of :func:`coherent_normals` at ``X`` along each column of ``Y``.

    For a face with :math:`c = (x_b - x_a) \\times (x_c - x_a)` and unit normal :math:`u = c / \\|c\\|`,
    :math:`\\dot u = (I - u u^T)\\, \\dot c / \\|c\\|`; at a vertex, :math:`\\dot s_i = \\sum_{f \\ni i} \\dot u_f` and

    .. math:: \\dot N_i = \\frac{(I - N_i N_i^T)\\, \\dot s_i}{\\|s_i\\|} \\ \\text{where}\\ \\|s_i\\| > k_i / 2,
              \\qquad \\dot N_i = \\frac{\\dot s_i}{k_i / 2} \\ \\text{otherwise}.

    Zero-area faces contribute nothing (their normal is held at zero).

    Parameters
    ----------
    X : (n, 3) float64
    F : (m, 3) int
    Y : (n, 3, k) float64
        ``k`` directions (vertex displacements).
    chunk : int
        Directions handled at once (bounds the (m, 3, chunk) temporaries).

    Returns
    -------
    (n, 3, k) float64
        :math:`\\frac{d}{dt} N(X + t Y_{:,:,j})` at ``t = 0`` for each ``j``.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]])
    >>> Y = np.zeros((3, 3, 1)); Y[0, 2, 0] = 1.0  # lift the corner at the right angle
    >>> coherent_normals_derivative(V, np.array([[0, 1, 2]]), Y)[1, :, 0].tolist()
    [1.0, 1.0, 0.0]
    """
    n, k = X.shape[0], Y.shape[2]
    e1, e2 = X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]]
    c = cross_rows(e1, e2)
    c_norm = np.linalg.norm(c, axis=1)
    u = np.divide(c, c_norm[:, None], out=np.zeros_like(c), where=c_norm[:, None] > 0)
    inv_c = np.divide(1.0, c_norm, out=np.zeros_like(c_norm), where=c_norm > 0)
    s = _scatter_faces_to_vertices(u, F, n)
    s_norm = np.linalg.norm(s, axis=1)
    half_k = 0.5 * np.bincount(F.ravel(), minlength=n).astype(np.float64)
    unit = s_norm > half_k  # vertices whose normal is normalised (else divided by k/2)
    N = np.divide(s, s_norm[:, None], out=np.zeros_like(s), where=unit[:, None])
    scale = np.divide(1.0, np.where(unit, s_norm, half_k), out=np.zeros(n), where=np.where(unit, s_norm, half_k) > 0)
    incidence = vertex_face_incidence(F, n)
    out = np.empty((n, 3, k))
    for j0 in range(0, k, chunk):  # over blocks of directions, each vectorised over faces
        Yj = Y[:, :, j0:j0 + chunk]
        d1, d2 = Yj[F[:, 1]] - Yj[F[:, 0]], Yj[F[:, 2]] - Yj[F[:, 0]]
        dc = np.cross(d1, e2[:, :, None], axis=1) + np.cross(e1[:, :, None], d2, axis=1)
        du = (dc - u[:, :, None] * np.sum(u[:, :, None] * dc, axis=1, keepdims=True)) * inv_c[:, None, None]
        ds = (incidence @ du.reshape(F.shape[0], -1)).reshape(n, 3, -1)
        ds -= unit[:, None, None] * N[:, :, None] * np.sum(N[:, :, None] * ds, axis=1, keepdims=True)
        out[:, :, j0:j0 + chunk] = ds * scale[:, None, None]
    return out


def signed_volume(V: np.ndarray, F: np.ndarray, origin: np.ndarray | None = None) -> float:
    """Signed volume enclosed by a closed, consistently oriented mesh (divergence theorem).

    .. math:: \\mathrm{vol} = \\frac16 \\sum_{(a,b,c) \\in F} (a - o) \\cdot ((b - o) \\times (c - o))

    For a closed mesh the result does not depend on ``origin``; for an open mesh it is
    the signed volume of the cone from ``origin`` (default: the vertex centroid) to the
    surface.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> round(signed_volume(V, F), 12)
    0.166666666667
    """
    o = V.mean(axis=0) if origin is None else np.asarray(origin, dtype=np.float64)
    a, b, c = V[F[:, 0]] - o, V[F[:, 1]] - o, V[F[:, 2]] - o
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def cotangent_laplacian(V: np.ndarray, F: np.ndarray) -> sp.csr_matrix:
    """Cotangent Laplacian, CSR (n, n): positive semi-definite, rows summing to zero.

    .. math:: L_{ij} = -\\tfrac12 (\\cot \\alpha_{ij} + \\cot \\beta_{ij}), \\quad L_{ii} = -\\sum_{j \\ne i} L_{ij}

    with :math:`\\alpha_{ij}, \\beta_{ij}` the angles opposite edge ij (Pinkall and
    Polthier 1993). Zero-area faces contribute nothing.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]])
    >>> cotangent_laplacian(V, np.array([[0, 1, 2]])).toarray()
    array([[ 1. , -0.5, -0.5],
           [-0.5,  0.5,  0. ],
           [-0.5,  0. ,  0.5]])
    """
    n = V.shape[0]
    rows, cols, vals = [], [], []
    area2 = np.linalg.norm(_cross(V, F), axis=1)
    ok = area2 > 0
    for k in range(3):
        i, j, o = F[:, (k + 1) % 3], F[:, (k + 2) % 3], F[:, k]
        u, v = V[i] - V[o], V[j] - V[o]
        cot = np.zeros(F.shape[0])
        np.divide(np.einsum("ij,ij->i", u, v), area2, out=cot, where=ok)
        rows += [i, j]
        cols += [j, i]
        vals += [-0.5 * cot, -0.5 * cot]
    off = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
    )
    diag = -np.asarray(off.sum(axis=1)).ravel()
    return sp.csr_matrix(off + sp.diags(diag))


def lumped_mass(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Barycentric lumped vertex areas: a third of the area of each incident face, shape (n,).

    Examples
    --------
    >>> import numpy as np
    >>> lumped_mass(np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    array([0.16666667, 0.16666667, 0.16666667])
    """
    return _scatter_faces_to_vertices(face_areas(V, F) / 3.0, F, V.shape[0])
