""":func:`denoise`: the one entry the API, the CLI's ``denoise`` and the pipeline's ``denoise`` step share.

With no method it runs the default for scans (:mod:`meshdenoise.policy`: candidates scored by
held-out vertices, the least error kept, its flipped faces guarded); with a method, that filter,
every parameter its automatic rule tunes and the caller did not give chosen by that rule
(:func:`method_parameters`), or with ``defaults=True`` the filter's own defaults (what
:func:`meshdenoise.apply_filter` runs). The command line's ``denoise --method M [--defaults]`` and
a pipeline's ``denoise`` step with ``method: M`` mean the same.
"""

from __future__ import annotations

import logging
from typing import Any

from .policy import DefaultChoice, DefaultConfig, choose_default, run_default
from .progress import stage
from .registry import KEYWORD_OPTIONS, apply_filter, get_filter
from .tuning.choose import choose_parameters, rule_criterion
from .tuning.memo import release_before_filter

__all__ = ["DefaultChoice", "DefaultConfig", "choose_default", "denoise", "method_parameters"]

log = logging.getLogger(__name__)


def method_parameters(
    mesh: Any,
    method: str,
    *,
    noise: Any = None,
    criterion: str | None = None,
    defaults: bool = False,
    **params: Any,
) -> tuple[dict, str | None]:
    """The parameters :func:`denoise` runs ``method`` with, and the criterion that chose them.

    Every parameter the filter's automatic rule tunes (``spec.auto.tunes``) and ``params`` does not
    hold is chosen by that rule, for the face-normal error where the filter has that criterion
    (:func:`~meshdenoise.tuning.choose.rule_criterion`); the parameters given are held fixed during
    the choice. Nothing is chosen when all of them are given, when the filter has no rule, or with
    ``defaults=True`` (the filter's defaults then stand for the parameters not given).

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    method : str
        A registered filter.
    noise : float or NoiseModel, optional
        The noise level to choose for; estimated when not given.
    criterion : {"normals", "sure", "gcv"}, optional
        What the choice minimises (the filter's own default when not given).
    defaults : bool
        Choose nothing: the filter's own defaults for the parameters not given.
    **params
        The filter's parameters given (held fixed).

    Returns
    -------
    params : dict
        The parameters given and those chosen (not checked: the filter checks them when it runs).
    criterion : str or None
        The criterion of the choice, ``None`` when nothing was chosen.

    Raises
    ------
    TypeError
        ``noise`` or ``criterion`` with ``defaults=True`` (they say how to choose, and nothing is chosen).
    """
    if defaults:
        for name, value in (("criterion", criterion), ("noise", noise)):
            if value is not None:
                raise TypeError(f"denoise: {name}={value!r} says how to choose {method}'s parameters; "
                                "defaults=True chooses none (leave one of them out)")
        return dict(params), None
    spec = get_filter(method)
    if spec.auto is None or not set(spec.auto.tunes) - set(params):
        return dict(params), None
    used = rule_criterion(method, criterion)
    chosen = choose_parameters(mesh, method, noise=noise, criterion=used, **params)
    log.info("denoise(%s): automatic parameters %s", method, chosen)
    release_before_filter()  # the choice's memo entries are dead weight beside the filter
    return chosen, used


def denoise(
    mesh: Any,
    method: str | None = None,
    *,
    noise: float | None = None,
    return_params: bool = False,
    boundary_motion: str = "normal",
    criterion: str | None = None,
    defaults: bool = False,
    config: DefaultConfig | None = None,
    **params: Any,
) -> Any:
    """Denoise a mesh; with no method, the default for scans chooses the filter and its parameters.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    method : str, optional
        A registered filter, its parameters not given chosen by its own automatic rule
        (:func:`method_parameters`). ``None`` (default): the default
        (:func:`meshdenoise.policy.run_default`) scores its candidate filters along their runs on
        held-out vertices and runs the one of least estimated face-normal error.
    noise : float or NoiseModel, optional
        With a method whose parameters are chosen: the noise level (or level and correlation length)
        if known, else estimated. The default needs none (not with ``method=None``).
    return_params : bool
        Also return the parameters used: with a method, the dict of parameters; with none, the
        :class:`~meshdenoise.policy.DefaultChoice`.
    boundary_motion : {"normal", "free"}
        ``"normal"`` (default): vertices on open borders move only along their normals, so borders do
        not shrink inward (:func:`meshdenoise.registry.boundary_along_normals`); ``"free"``: the filter
        as it is (what ``apply_filter`` does).
    criterion : {"normals", "sure", "gcv"}, optional
        With a method and its parameters chosen automatically, how (docs/automatic-parameters.md).
        Not with ``method=None``.
    defaults : bool
        With a method: choose nothing, run the filter's own defaults for the parameters not given
        (``apply_filter`` but for ``boundary_motion``'s default); the command line's ``--defaults``.
    config : DefaultConfig, optional
        The default's settings (``method=None`` only).
    **params
        Filter parameters (held fixed) and the common options (``pinned``, ``region``,
        ``preserve_volume``, ``operators``). With a method, every parameter its rule tunes that is
        not given here is chosen automatically (unless ``defaults=True``).

    Returns
    -------
    Same type as ``mesh`` (a MeshSet is changed in place), or ``(mesh, params or choice)``.

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise import add_normal_noise, normal_error_deg
    >>> V, F = icosphere(3)
    >>> Vn, _ = add_normal_noise((V, F), rho=0.02, seed=0)
    >>> (Vd, Fd), choice = denoise((Vn, F), return_params=True)
    >>> bool(normal_error_deg((V, F), Vd) < 0.5 * normal_error_deg((V, F), Vn))
    True
    >>> _, used = denoise((Vn, F), method="sobolev", defaults=True, return_params=True)
    >>> used
    {}
    """
    options = {k: params.pop(k) for k in list(params) if k in KEYWORD_OPTIONS}
    options["boundary_motion"] = boundary_motion
    if method is None:
        if params:
            raise TypeError(f"denoise: filter parameters {sorted(params)} need method=; "
                            "with no method the default chooses the filter and its parameters")
        for name, value in (("criterion", criterion), ("noise", noise), ("defaults", defaults or None)):
            if value is not None:
                raise TypeError(f"denoise: {name}={value!r} needs method=; the default chooses the filter and its "
                                "parameters, reading the noise from held-out vertices")
        out, choice = run_default(mesh, config, **options)
        return (out, choice) if return_params else out
    if config is not None:
        raise TypeError("denoise: config= is the default's (method=None)")
    if not isinstance(method, str):
        raise TypeError(f"denoise: method must be a filter name (str) or None, got {method!r}")
    if not isinstance(defaults, bool):
        raise TypeError(f"denoise: defaults must be True or False, got {defaults!r}")
    chosen, _ = method_parameters(mesh, method, noise=noise, criterion=criterion, defaults=defaults, **params)
    with stage(f"running {method}"):
        out = apply_filter(method, mesh, **chosen, **options)
    return (out, chosen) if return_params else out
