"""meshdenoise: mesh-denoising filters for pymeshlab, Open3D and numpy arrays.

Every filter takes a ``(V, F)`` tuple, a ``pymeshlab.MeshSet`` (changed in place), a
``pymeshlab.Mesh`` or an ``open3d.geometry.TriangleMesh`` and returns the same type.

>>> import numpy as np, meshdenoise
>>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
>>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
>>> V1, F1 = meshdenoise.sobolev((V, F), mu=0.5)
>>> {"filtering", "heat", "sobolev", "sinkhorn"} <= {f.name for f in meshdenoise.list_filters()}
True
"""

from ._launch import exit_at_once_on_interrupt, exit_if_the_command

exit_at_once_on_interrupt()  # in the meshdenoise program only, until its main() runs
try:  # Ctrl-C while the command line loads these: exit 130, no traceback (meshdenoise._launch)
    from .registry import add_plugin_loader as _add_plugin_loader

    @_add_plugin_loader
    def _load_plugins() -> None:
        from . import plugins  # noqa: F401  (importing registers every filter; the registry names none)

    from .adapters import to_arrays
    from .arrays import MeshValidationError
    from .metrics import max_distance, mean_distance, normal_error_deg, snr, volume_change
    from .noise import add_normal_noise, add_scanner_noise
    from .scanner import RangeScan, ScannerSettings, simulate_scan
    from .operators import Operators, get_operators
    from .plugins.filtering import filtering
    from .plugins.heat import heat
    from .plugins.sinkhorn import sinkhorn
    from .plugins.two_stage import two_stage
    from .plugins.sobolev import SobolevSolver, sobolev
    from .plugins.sobolev_axes import sobolev_axes
    from .plugins.sobolev_normal import sobolev_normal
    from .plugins.sobolev_gls import sobolev_gls
    from .plugins.sobolev_bilaplacian import sobolev_bilaplacian
    from .plugins.taubin import taubin
    from .tuning import auto_filters, choose_parameters, estimate_noise
    from .default import DefaultChoice, DefaultConfig, choose_default, denoise
    from .cache import clear_caches
    from .io import MeshFile, MeshFileError, PlyExtras, load_mesh, save_mesh
    from .meshinfo import mesh_info
    from .metrics import compute_metrics
    from .registry import Param, apply_filter, get_filter, list_filters, register
except KeyboardInterrupt:
    exit_if_the_command()
    raise

__version__ = "0.1.0"

def __getattr__(name: str):
    # the pipeline engine pulls in Dask: load it only when asked for
    if name in ("load_pipeline", "run_pipeline"):
        from . import pipeline

        return getattr(pipeline, name)
    if name == "render_comparison":  # rendering and reports load matplotlib and Open3D's renderer on demand
        from .render import render_comparison

        return render_comparison
    if name == "write_report":
        from .report import write_report

        return write_report
    raise AttributeError(f"module 'meshdenoise' has no attribute {name!r}")


__all__ = [
    "taubin",
    "sobolev_bilaplacian",
    "sobolev_axes",
    "sobolev_normal",
    "sobolev_gls",
    "two_stage",
    "normal_error_deg",
    "mean_distance",
    "max_distance",
    "volume_change",
    "compute_metrics",
    "estimate_noise",
    "choose_parameters",
    "denoise",
    "choose_default",
    "DefaultConfig",
    "DefaultChoice",
    "auto_filters",
    "clear_caches",
    "mesh_info",
    "load_pipeline",
    "run_pipeline",
    "render_comparison",
    "write_report",
    "load_mesh",
    "save_mesh",
    "MeshFile",
    "PlyExtras",
    "MeshFileError",
    "filtering",
    "heat",
    "sinkhorn",
    "sobolev",
    "add_normal_noise", "add_scanner_noise", "simulate_scan", "RangeScan", "ScannerSettings",
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
