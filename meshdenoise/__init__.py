"""meshdenoise: mesh-denoising filters for pymeshlab, Open3D and numpy arrays.

Every filter takes a ``(V, F)`` tuple, a ``pymeshlab.MeshSet`` (changed in place), a
``pymeshlab.Mesh`` or an ``open3d.geometry.TriangleMesh`` and returns the same type.

>>> import numpy as np, meshdenoise
>>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
>>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
>>> V1, F1 = meshdenoise.sobolev((V, F), mu=0.5)
>>> sorted(f.name for f in meshdenoise.list_filters())[:4]
['filtering', 'heat', 'sinkhorn', 'sobolev']
"""

from .adapters import to_arrays
from .arrays import MeshValidationError
from .metrics import snr
from .noise import add_normal_noise
from .operators import Operators, get_operators
from .plugins.filtering import filtering
from .plugins.heat import heat
from .plugins.sinkhorn import sinkhorn
from .plugins.sobolev import SobolevSolver, sobolev
from .registry import Param, apply_filter, get_filter, list_filters, register

__version__ = "0.1.0"

__all__ = [
    "filtering",
    "heat",
    "sinkhorn",
    "sobolev",
    "add_normal_noise",
    "snr",
    "apply_filter",
    "get_filter",
    "list_filters",
    "register",
    "Param",
    "Operators",
    "get_operators",
    "SobolevSolver",
    "to_arrays",
    "MeshValidationError",
]
