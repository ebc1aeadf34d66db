"""One registry of filters, shared by the Python API, the CLI and the YAML pipelines.

A filter is written once, as an array-core function::

    @register("filtering", params=[Param("iterations", int, 10, low=0)], summary="...")
    def filtering(V, F, *, ops, pinned, iterations):
        '''numpydoc docstring shown to users'''
        return new_V

and :func:`register` returns the public function, which accepts every mesh type of
:mod:`meshdenoise.adapters`, checks each parameter's type and range, resolves the
common options (``pinned=``, ``region=``, ``preserve_volume=``, ``operators=``) and
converts the result back to the caller's mesh type.
"""

from __future__ import annotations

import difflib
import functools
import inspect
import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

__all__ = [
    "Param", "AutoRule", "FilterSpec", "register", "get_filter", "list_filters", "apply_filter", "REGISTRY",
    "parse_number", "MAX_ITERATIONS", "ParameterError", "UnknownFilterError", "FilterOption", "COMMON_OPTIONS",
    "KEYWORD_OPTIONS", "STEP_OPTIONS", "ParameterTypeError", "ParameterValueError",
]


class ParameterError(ValueError):
    """Parameters each in their range that fail together on this mesh (a singular system, an overflow,
    non-finite output); the message names the filter or its parameters.

    A filter's core raises it (rather than a plain ``ValueError``) when its message already names the
    parameters and their values (``heat``'s ``tau`` out of its stable range on this mesh): the registry
    passes it on as it is, and words any other failure of the core itself (:func:`_run_filter`).
    """


class _AboutParameter:
    """The error of one parameter: :attr:`parameter` names it, so that a caller can point at it (a pipeline's
    error names the line of that key in its file) without reading the message."""

    def __init__(self, message: str = "", parameter: str | None = None) -> None:
        super().__init__(message)
        self.parameter = parameter


class ParameterTypeError(_AboutParameter, TypeError):
    """A parameter given a value of the wrong type, or a parameter the filter does not have."""


class ParameterValueError(_AboutParameter, ValueError):
    """A parameter's value out of its range or not among its choices."""


#: Upper bound of every iteration or step count (``iterations``, heat's ``ceil(time / tau)``...):
#: a count above it would run for hours and is refused before anything is allocated.
MAX_ITERATIONS = 100_000


def parse_number(value: Any, kind: type) -> int | float:
    """``value`` as ``kind`` (``int`` or ``float``): the one conversion of numbers given as text or numbers.

    The command line (``--param mu=1e-3``, ``--set mu=1e-3``) and YAML files (PyYAML reads
    ``mu: 1e-3`` as the *string* ``'1e-3'``: YAML 1.1's float rule wants a dot) all come here; the
    YAML reader of all three (:class:`~meshdenoise.pipeline.yamlsource.NumberLoader`) reads its
    numbers with this function too and leaves YAML 1.1's other forms (``0x10``, ``0b11``, octal
    ``010``, base-60 ``1:30``) as text, which this refuses (``010`` is 10).
    A string is accepted when Python's ``float()`` accepts it; an ``int`` parameter takes an
    integral number however written (``10``, ``1e3``, ``10.0``), never a fraction.

    Raises
    ------
    TypeError
        Not a number (``True`` is not a number), or a fraction for an ``int``.
    OverflowError
        An integer too large for a ``float``.

    Examples
    --------
    >>> parse_number("1e-3", float), parse_number("1e3", int), parse_number(" 7 ", int)
    (0.001, 1000, 7)
    """
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"expected a number, got {value!r}")
    if isinstance(value, str):
        text = value.strip()
        if kind is int:
            try:
                return int(text)  # exact, however many digits
            except ValueError:
                pass
        try:
            value = float(text)
        except ValueError:
            raise TypeError(f"expected a number, got {value!r}") from None
    elif not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"expected a number, got {value!r}")
    if kind is int:
        if isinstance(value, (float, np.floating)):
            if not (math.isfinite(value) and float(value).is_integer()):
                raise TypeError(f"expected an integer, got {value!r}")
        return int(value)
    return float(value)


@dataclass(frozen=True)
class Param:
    """A typed, range-checked filter parameter.

    Parameters
    ----------
    name : str
    kind : type
        ``int``, ``float``, ``bool`` or ``str``.
    default : object
    low, high : float, optional
        Bounds; closed unless ``low_open`` / ``high_open``.
    choices : tuple of str, optional
        Allowed values of a ``str`` parameter.
    help : str
        One line for ``meshdenoise filters`` and error messages.
    """

    name: str
    kind: type
    default: Any
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple | None = None
    help: str = ""

    def range_text(self) -> str:
        """The allowed values in words, e.g. ``0 < tau <= 2`` or ``one of 'a', 'b'``."""
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.kind is bool:
            return "True or False"
        parts = []
        if self.low is not None:
            parts.append(f"{self.low:g} {'<' if self.low_open else '<='} ")
        parts.append(self.name)
        if self.high is not None:
            parts.append(f" {'<' if self.high_open else '<='} {self.high:g}")
        if self.low is None and self.high is None:
            return f"any {self.kind.__name__}"
        return "".join(parts)

    def check(self, value: Any, where: str = "") -> Any:
        """Return ``value`` converted to this parameter's type, or raise with the allowed range.

        Raises
        ------
        ParameterTypeError
            Wrong type (``True`` is not an ``int``; ``2.5`` is not an ``int``); a ``TypeError``.
        ParameterValueError
            Out of range or not among the choices; the message names the parameter,
            the value and the allowed range; a ``ValueError``. Both carry ``parameter``, this one's name.
        """
        prefix = f"{where}: " if where else ""
        k = self.kind
        if k is bool:
            if not isinstance(value, (bool, np.bool_)):
                raise ParameterTypeError(f"{prefix}parameter '{self.name}' must be True or False, got {value!r}",
                                         self.name)
            return bool(value)
        if k is str:
            if not isinstance(value, str):
                raise ParameterTypeError(f"{prefix}parameter '{self.name}' must be a string, got {value!r}", self.name)
            if self.choices is not None and value not in self.choices:
                hint = difflib.get_close_matches(value, self.choices, n=1)
                extra = f" (did you mean {hint[0]!r}?)" if hint else ""
                raise ParameterValueError(
                    f"{prefix}parameter '{self.name}' = {value!r} is not allowed: {self.range_text()}{extra}",
                    self.name,
                )
            return value
        try:
            value = parse_number(value, k)
        except OverflowError:  # an integer of hundreds of digits for a float parameter
            raise ParameterValueError(f"{prefix}parameter '{self.name}' = {value!r} is too large for a float ({self.range_text()})",
                                      self.name) from None
        except TypeError:
            raise ParameterTypeError(f"{prefix}parameter '{self.name}' must be a{'n' if k is int else ''} {k.__name__}, got {value!r}",
                                     self.name) from None
        if k is float and not math.isfinite(value):
            raise ParameterValueError(f"{prefix}parameter '{self.name}' = {value!r} must be finite ({self.range_text()})",
                                      self.name)
        too_low = self.low is not None and (value <= self.low if self.low_open else value < self.low)
        too_high = self.high is not None and (value >= self.high if self.high_open else value > self.high)
        if too_low or too_high:
            raise ParameterValueError(f"{prefix}parameter '{self.name}' = {value!r} is out of range: {self.range_text()}",
                                      self.name)
        return value

    def describe(self) -> dict:
        """A JSON-friendly description (``meshdenoise filters --json``, docs).

        Keys: ``name``, ``type`` (``int``, ``float``, ``bool``, ``str``), ``default``, ``low``,
        ``high`` (``null`` when unbounded), ``low_open``, ``high_open``, ``choices`` (a list or
        ``null``), ``range`` (in words) and ``help``.
        """
        default = self.default
        if isinstance(default, tuple):
            default = list(default)
        return {
            "name": self.name,
            "type": self.kind.__name__,
            "default": default,
            "low": self.low,
            "high": self.high,
            "low_open": self.low_open,
            "high_open": self.high_open,
            "choices": None if self.choices is None else list(self.choices),
            "range": self.range_text(),
            "help": self.help,
        }


@dataclass(frozen=True)
class AutoRule:
    """A filter's automatic rule: which parameters it chooses, and how.

    ``choose(ctx)`` takes a :class:`~meshdenoise.tuning.context.TuningContext` and returns
    ``(chosen parameters, best point)`` (a :class:`~meshdenoise.tuning.risk.Point`); it
    chooses the parameters in ``tunes`` that ``ctx.given`` does not hold: the rule by SURE
    (``criterion="sure"``, also ``"gcv"`` and ``"oracle"``).

    ``normals`` names the parameter that sets how much a filter smooths (a weight, an iteration
    count, a diffusion time): the filter takes ``criterion="normals"``
    (:func:`~meshdenoise.tuning.choose.choose_parameters`), the least error of the face normals.
    ``held_out``: a :class:`~meshdenoise.tuning.sweep.HeldOutRule` choosing for that criterion by
    held-out vertices (the least held-out face-normal loss along a sweep of the parameter). Without
    one the rule's SURE choice is moved to the least estimated face-normal error
    (:func:`~meshdenoise.tuning.normal_risk.refine_for_normals`), which reads the fields below. A
    tuple of names is scaled together by one factor (``sobolev_axes``' three weights). Declaring
    ``normals`` without ``held_out`` promises that the filter is linear in the coordinates, the same
    on each axis, for every parameter value its rule accepts, or gives ``linear_map``:
    ``linear_map(V, F, ops, params)`` returns the filter's map with what it reads of the mesh (a
    frame) taken from ``V`` and held, as a function of an ``(n, 3k)`` block of ``k`` coordinate
    triples, each mapped as the filter maps positions (``sobolev_axes``, whose axes come from the
    mesh). ``normals_region``: the size of the sampled region the normals search runs on (default
    :data:`~meshdenoise.tuning.choose.NORMAL_REGION`), from twice that many vertices, for a filter
    whose candidates are costly. ``spectral``: ``spectral(V, F, ops, params)`` gives the filter's map
    at ``params`` (what it reads of the mesh taken from ``V``, as for ``linear_map``) as functions of
    one symmetric matrix (:class:`~meshdenoise.tuning.spectral.Spectral`), or ``None`` for a
    configuration that is not: the normals search then scores its candidates by Lanczos runs, with
    no filter run per candidate (``refine_for_normals(spectral=...)``).
    """

    tunes: tuple[str, ...]
    choose: Callable[[Any], tuple[dict, Any]]
    normals: str | tuple[str, ...] | None = None
    held_out: Any = None
    linear_map: Callable[..., Callable[[Any], Any]] | None = None
    normals_region: int | None = None
    spectral: Callable[..., Any] | None = None


@dataclass(frozen=True)
class FilterSpec:
    """A registered filter: its name, parameters, array core, automatic rule and public function."""

    name: str
    summary: str
    params: tuple[Param, ...]
    core: Callable
    linear: bool = False
    translation_equivariant: bool = True
    auto: AutoRule | None = None
    scale_free: bool = False
    public: Callable | None = field(default=None, compare=False)
    along_normals: Callable[[dict], bool] | None = None
    warm_start: bool = False
    border_draft: Callable[[dict], dict] | None = None
    rough_free_run: bool = False

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(name)

    def resolve(self, given: dict, where: str = "") -> dict:
        """Check the given parameters (names, types, ranges) and fill in defaults.

        Raises
        ------
        ParameterTypeError, ParameterValueError
            As :meth:`Param.check`; an unknown name is a ``ParameterTypeError`` whose ``parameter`` is that name.
        """
        known = {p.name for p in self.params}
        prefix = f"{where}: " if where else f"filter '{self.name}': "
        for key in given:
            if key not in known:
                hint = difflib.get_close_matches(key, sorted(known | KEYWORD_OPTIONS), n=1)
                extra = f" (did you mean '{hint[0]}'?)" if hint else ""
                allowed = ", ".join(sorted(known)) or "none"
                raise ParameterTypeError(f"{prefix}unknown parameter '{key}'{extra}; its parameters are: {allowed}", key)
        return {p.name: p.check(given.get(p.name, p.default), prefix.rstrip(": ")) for p in self.params}


@dataclass(frozen=True)
class FilterOption:
    """An option every registered filter takes besides its own parameters: one record of :data:`COMMON_OPTIONS`.

    Parameters
    ----------
    name : str
    type : str
        Its type in words, for ``meshdenoise filters --json`` and ``meshdenoise steps`` (``"str|list"``).
    default : object
        Its value when not given (to a filter's function, or a pipeline's filter step).
    help : str
        One line for the listings.
    choices : tuple of str, optional
        The words it takes; with ``indices`` a list of vertex indices too.
    indices : bool
        Also takes a list of vertex indices (``pinned``, ``region``).
    range : str
        The allowed values in words when ``choices`` does not say them (``noise``).
    keyword : bool
        A keyword of every filter's function (``apply_filter``, ``meshdenoise.sobolev(...)``).
    step : bool
        A key of a pipeline's filter step (``operators`` is Python's only; ``parameters``, ``noise`` and
        ``criterion`` choose parameters, which a filter's function never does).
    """

    name: str
    type: str
    default: Any
    help: str
    choices: tuple[str, ...] | None = None
    indices: bool = False
    range: str = ""
    keyword: bool = True
    step: bool = True

    def range_text(self) -> str:
        """The allowed values in words, e.g. ``boundary, selection or vertex indices``."""
        if self.choices is None:
            return self.range
        words = list(self.choices) + (["vertex indices"] if self.indices else [])
        return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " or " + words[-1]

    def describe(self) -> dict:
        """``{"name", "type", "default", "range", "help"}`` (``meshdenoise filters --json``'s ``filter_options``)."""
        return {"name": self.name, "type": self.type, "default": self.default, "range": self.range_text(),
                "help": self.help}


BOUNDARY_MOTIONS = ("free", "normal")  # the ``boundary_motion`` option: see boundary_along_normals

#: The options every filter takes besides its own parameters, declared once: the filters' signatures
#: (:func:`register`), the registry's run (:func:`_run_filter`), the pipeline's filter steps (their keys and
#: checks, ``meshdenoise steps``) and ``meshdenoise filters --json`` read them from here.
COMMON_OPTIONS: tuple[FilterOption, ...] = (
    FilterOption("pinned", "str|list", None, "vertices kept exactly fixed", choices=("boundary", "selection"),
                 indices=True),
    FilterOption("region", "str|list", None, "only these vertices move", choices=("selection",), indices=True),
    FilterOption("preserve_volume", "bool", False, "rescale so the enclosed volume equals the input's",
                 range="True or False"),
    FilterOption("operators", "Operators", None, "the mesh's cached operators (meshdenoise.get_operators), built "
                 "when not given", range="Operators of this mesh's faces", step=False),
    FilterOption("boundary_motion", "str", "free", "normal: vertices on open borders move along their normals only "
                 "(no inward shrinking); free: as the filter moves them", choices=BOUNDARY_MOTIONS),
    FilterOption("parameters", "str", None, "choose the parameters not given from the mesh, by the filter's own rule "
                 "(recorded in the results as auto.<filter>.<param>)", choices=("auto",), keyword=False),
    FilterOption("noise", "str|float", None, "the noise level to choose the parameters for instead of the estimate: "
                 "RHO in mesh units or in mean edge lengths with h (0.4h), L the correlation length in mean edge "
                 "lengths (0.4h,2)", range="RHO[h][,L], RHO >= 0, L >= 0", keyword=False),
    FilterOption("criterion", "str", "sure", "what the choice of the parameters minimises: sure, the estimated "
                 "position error (SNR); normals (linear filters), the face-normal error: what a rendering shows, "
                 "smoothing and shrinking more", choices=("sure", "normals"), keyword=False),
)
#: Keywords of every filter's function besides its parameters.
KEYWORD_OPTIONS = frozenset(o.name for o in COMMON_OPTIONS if o.keyword)
#: Keys of a pipeline's filter step besides the filter's parameters.
STEP_OPTIONS = frozenset(o.name for o in COMMON_OPTIONS if o.step)
REGISTRY: dict[str, FilterSpec] = {}


def register(
    name: str,
    *,
    params: list[Param],
    summary: str,
    linear: bool = False,
    translation_equivariant: bool = True,
    auto: AutoRule | None = None,
    scale_free: bool = False,
    along_normals: Callable[[dict], bool] | None = None,
    warm_start: bool = False,
    border_draft: Callable[[dict], dict] | None = None,
    rough_free_run: bool = False,
) -> Callable[[Callable], Callable]:
    """Register an array-core filter and return its public, mesh-type-agnostic function.

    ``auto`` is the filter's automatic rule (:class:`AutoRule`), used by
    :func:`meshdenoise.choose_parameters` and :func:`meshdenoise.denoise`; its ``tunes``
    must name parameters of the filter. ``scale_free=True`` says the filter commutes with
    scaling (no parameter in length units): the core then runs on ``V / s`` and its result
    is multiplied by ``s``, a power of two near the mesh's size, which is exact in floating
    point and keeps squared lengths and cross products of huge or tiny meshes (1e80, 1e-80)
    from overflowing or underflowing. ``along_normals(values)`` (resolved parameters) says whether
    a run with those parameters already moves every vertex along its own vertex normal only
    (``two_stage`` with ``keep_tangential``): ``boundary_motion="normal"`` then keeps the free run
    (:func:`boundary_along_normals`). ``warm_start=True``: the core also takes ``start``, ``None`` or a read-only
    ``(n, 3)`` result of the same filter on a nearby input (the border option's free run before its held run, or
    its ``border_draft``'s), which its iterative solves may start from; its result is the same to their tolerance.
    ``border_draft(values)``: the parameters of a cheaper run of the same filter that stands for its free run in
    ``boundary_motion="normal"`` (the border's normal moves read from it); the core then also takes ``draft``,
    ``None`` or that run's read-only ``(n, 3)`` result, given to the held run, which may build on it:
    ``sobolev_gls``' isotropic pass, whose normals its held run takes. ``rough_free_run=True``: the core also takes
    ``rough``, ``True`` on that free run (or its ``border_draft``'s), whose result is read only for the border's
    normal moves and as the held run's start or draft: its Lanczos solves may stop at
    :data:`~meshdenoise.solvers.DRAFT_LANCZOS_TOL` instead of the filter's own tolerance.

    The core is called as ``core(V, F, ops=ops, pinned=pinned, **params)`` with ``V``
    read-only ``(n, 3) float64``, ``F (m, 3) int64``, ``ops`` the cached
    :class:`~meshdenoise.operators.Operators` and ``pinned`` a boolean mask of the
    vertices that must not move (or ``None``). It returns the new ``(n, 3)`` array.
    """
    if name in REGISTRY:
        raise ValueError(f"a filter named {name!r} is already registered")
    for hook, value in (("along_normals", along_normals), ("border_draft", border_draft)):
        if value is not None and not callable(value):
            raise TypeError(f"register({name!r}): {hook}= must be a function of the parameters or None, got {value!r}")
    for flag, value in (("warm_start", warm_start), ("rough_free_run", rough_free_run)):
        if not isinstance(value, bool):
            raise TypeError(f"register({name!r}): {flag}= must be True or False, got {value!r}")
    if auto is not None:
        unknown = set(auto.tunes) - {p.name for p in params}
        if not isinstance(auto, AutoRule) or unknown:
            raise ValueError(f"register({name!r}): auto= must be an AutoRule tuning the filter's parameters, got {auto!r}")

    def decorate(core: Callable) -> Callable:
        spec = FilterSpec(name, summary, tuple(params), core, linear, translation_equivariant, auto, scale_free,
                          along_normals=along_normals, warm_start=warm_start, border_draft=border_draft,
                          rough_free_run=rough_free_run)

        @functools.wraps(core)
        def public(mesh, **kwargs):
            return _run_filter(spec, mesh, kwargs)

        sig = [inspect.Parameter("mesh", inspect.Parameter.POSITIONAL_OR_KEYWORD)]
        sig += [inspect.Parameter(p.name, inspect.Parameter.KEYWORD_ONLY, default=p.default) for p in params]
        sig += [inspect.Parameter(o.name, inspect.Parameter.KEYWORD_ONLY, default=o.default)
                for o in COMMON_OPTIONS if o.keyword]
        public.__signature__ = inspect.Signature(sig)  # takes precedence over the core's (__wrapped__)
        object.__setattr__(spec, "public", public)
        REGISTRY[name] = spec
        return public

    return decorate


def _run_filter(spec: FilterSpec, mesh: Any, kwargs: dict) -> Any:
    # Imported here: adapters and constraints import the registry's users, not the reverse.
    from .adapters import read_mesh
    from .arrays import MeshValidationError
    from .constraints import check_encloses_volume, fixed_mask, restore_volume
    from .locality import relabelling
    from .operators import Operators, get_operators

    options = {k: kwargs.pop(k) for k in list(kwargs) if k in KEYWORD_OPTIONS}
    values = spec.resolve(kwargs)
    preserve_volume = options.get("preserve_volume", False)
    if not isinstance(preserve_volume, (bool, np.bool_)):
        raise TypeError(f"filter '{spec.name}': preserve_volume must be True or False, got {preserve_volume!r}")
    data = read_mesh(mesh)
    V, F = data.V, data.F
    ops = options.get("operators")
    relabel = None
    if ops is None:
        relabel = relabelling(F, V.shape[0])  # a large mesh in a cache-hostile order: filter relabelled vertices
        # the caller's labels need operators only to read pinned / region (e.g. "boundary"); else none are built
        needs_own = relabel is None or options.get("pinned") is not None or options.get("region") is not None
        ops = get_operators(F, V.shape[0]) if needs_own else None
    elif not isinstance(ops, Operators) or ops.n != V.shape[0] or not np.array_equal(ops.F, F):
        raise ValueError(f"filter '{spec.name}': operators= was built for another topology than this mesh")
    boundary_motion = options.get("boundary_motion", "free")
    if not isinstance(boundary_motion, str) or boundary_motion not in BOUNDARY_MOTIONS:
        raise ValueError(
            f"filter '{spec.name}': parameter 'boundary_motion' = {boundary_motion!r} is not one of "
            + ", ".join(map(repr, BOUNDARY_MOTIONS))
        )
    try:  # an index out of range for this mesh, a selection of another size: this mesh refuses the option
        pinned = None if ops is None else fixed_mask(ops, options.get("pinned"), options.get("region"), data)
        if preserve_volume:
            check_encloses_volume(V, F)  # before the filter runs: a flat mesh has no volume to keep
    except ValueError as exc:
        raise ParameterError(f"filter '{spec.name}': {exc}") from None
    try:
        if relabel is None:
            V_out = run_core(spec, V, ops, values, pinned=pinned, boundary_motion=boundary_motion)
        else:
            V_out = relabel.restore(run_core(spec, relabel.vertices(V), get_operators(relabel.faces, V.shape[0]),
                                             values, pinned=relabel.mask(pinned), boundary_motion=boundary_motion))
    except (MeshValidationError, ParameterError):  # the mesh's fault, or a core's message naming its parameters
        raise
    except (ValueError, ArithmeticError, RuntimeError, np.linalg.LinAlgError) as exc:
        text = str(exc) or type(exc).__name__
        raise ParameterError(
            f"filter '{spec.name}' with {_settings_text(values)} failed on this mesh: {text} "
            "(a parameter is too large or too small for it)"
        ) from exc
    if pinned is not None:
        V_out[pinned] = V[pinned]
    if preserve_volume:
        try:
            V_out = restore_volume(V, V_out, F, pinned)
        except ValueError as exc:  # no positive scale restores the volume of this result
            raise ParameterError(f"filter '{spec.name}' with {_settings_text(values)}: {exc}") from None
    if not np.isfinite(V_out).all():
        raise ParameterError(
            f"filter '{spec.name}' with {_settings_text(values)} produced non-finite coordinates "
            "(overflow: a parameter is too large or too small for this mesh)"
        )
    return data.write(V_out)


def run_core(spec: FilterSpec, V: np.ndarray, ops: Any, values: dict, *, pinned: np.ndarray | None = None,
             boundary_motion: str = "free") -> np.ndarray:
    """The filter's array core on ``V`` (n, 3) and ``ops.F``: a new (n, 3) float64 array, ``V`` untouched.

    A scale-free filter runs on ``V`` divided by a power of two near its extent (exact, so the
    result is the same, but nothing overflows or underflows), then is scaled back; with
    ``boundary_motion="normal"`` border vertices move along their normals only
    (:func:`boundary_along_normals`). ``values`` are resolved parameters (``spec.resolve``).
    Used by the public adapter; a caller that runs one filter many times on one topology can
    call it directly and skip the adapter's copies.
    """
    scale = power_of_two_scale(V) if spec.scale_free else 1.0
    V_in = V.view() if scale == 1.0 else V / scale
    V_in.flags.writeable = False  # a core must return new arrays, never write into its input
    first, rough = values, {}
    if boundary_motion == "normal" and _border_to_move(spec, ops, pinned, values) is not None:
        if spec.border_draft is not None:
            first = spec.border_draft(values)  # its result stands for the free run (its border's normal moves)
        if spec.rough_free_run:  # read for the border's moves and as the held run's start: a draft's tolerance
            rough = {"rough": True}
    V_out = np.asarray(spec.core(V_in, ops.F, ops=ops, pinned=pinned, **rough, **first), dtype=np.float64)
    if np.may_share_memory(V_out, V) or np.may_share_memory(V_out, V_in):
        V_out = V_out.copy()
    if boundary_motion == "normal":
        V_out = boundary_along_normals(spec, V_in, ops.F, ops, pinned, values, V_out)
    if scale != 1.0:
        V_out *= scale
    return V_out


def _border_to_move(spec: FilterSpec, ops: Any, pinned: np.ndarray | None, values: dict) -> np.ndarray | None:
    """The border vertices ``boundary_motion="normal"`` moves along their normals in a second run (bool (n,)), or
    ``None`` when there is no second run: no border vertex left free, or a run that already moves every vertex along
    its normal (:func:`boundary_along_normals`)."""
    b = ops.boundary_vertices if pinned is None else ops.boundary_vertices & ~pinned
    if not b.any() or (spec.along_normals is not None and spec.along_normals(values)):
        return None
    return b


def boundary_along_normals(
    spec: FilterSpec,
    V: np.ndarray,
    F: np.ndarray,
    ops: Any,
    pinned: np.ndarray | None,
    values: dict,
    V_free: np.ndarray,
) -> np.ndarray:
    """The ``boundary_motion="normal"`` option: open borders move only along their normals, then the rest follows.

    A smoother pulls a boundary vertex towards its one-sided neighbourhood, so open
    borders shrink inward (measured on a range scan: 4 to 5 times the interior's
    displacement). Here the filter runs once freely (``V_free``); each boundary vertex
    keeps only the part of its move along the vertex normal of ``V_free``,

    .. math:: x_b' = x_b + \\langle y_b - x_b, N_b \\rangle N_b ,

    which removes the noise across the surface (what a scanner adds) but not the inward
    pull; the filter then runs again with the boundary held at :math:`x_b'` as Dirichlet
    data, so the interior meets the border without a step. Costs a second run (started from the first where the
    filter takes a start, ``spec.warm_start``: face000's held ``sobolev_axes`` run 25 % fewer steps), except for a
    filter whose run with these parameters already moves every vertex along its own normal
    (``spec.along_normals(values)``: ``two_stage`` with ``keep_tangential``, whose vertices keep
    their input's tangential part): its free run is the result. On the range scan face000 with
    scanner noise its second run changed the border's error by 2 % (``benchmarks/results/borders.md``)
    and took as long as the first. A filter with a ``border_draft`` (``sobolev_gls``: its isotropic pass) has
    ``V_free`` from that cheaper run instead (:func:`run_core`), given to its held run as ``draft``: face000's
    ``sobolev_gls`` 5.0 -> 4.4 s, its normal error 8.42 -> 8.39 degrees, SNR 70.56 -> 70.60 dB, the border's mean
    error the same (0.508 edge lengths); its held run built on the draft (its normals, one correction solve):
    2.8 -> about 1.1 s.

    Parameters
    ----------
    spec : FilterSpec
    V : ndarray, shape (n, 3)
        The filter's input.
    F : ndarray, shape (m, 3)
    ops : Operators
    pinned : ndarray of bool, shape (n,), or None
        Vertices the caller holds fixed (they stay where they are).
    values : dict
        The filter's parameters.
    V_free : ndarray, shape (n, 3)
        The filter's output with a free boundary (or its ``border_draft``'s).

    Returns
    -------
    ndarray, shape (n, 3)
        The result, boundary vertices moved along their normals only.
    """
    from .geometry import vertex_normals

    b = _border_to_move(spec, ops, pinned, values)
    if b is None:
        return V_free
    N = vertex_normals(V_free, F)[b]
    along = np.einsum("ij,ij->i", V_free[b] - V[b], N)
    V_b = V[b] + along[:, None] * N
    V_held = np.array(V, dtype=np.float64)
    V_held[b] = V_b
    V_held.flags.writeable = False
    held = b if pinned is None else (b | pinned)
    start = V_free.view()
    start.flags.writeable = False  # a start is read, never written
    extra = {"start": start} if spec.warm_start else {}
    if spec.border_draft is not None:  # V_free is the draft's result: the held run may build on it
        extra["draft"] = start
    V_out = np.array(spec.core(V_held, F, ops=ops, pinned=held, **extra, **values), dtype=np.float64)
    V_out[b] = V_b  # exact Dirichlet values, whatever the solver's tolerance
    return V_out


def power_of_two_scale(V: np.ndarray) -> float:
    """A power of two near the longest side of the bounding box of ``V`` (1.0 for an empty or one-point mesh).

    Dividing by it is exact in floating point, so a scale-free filter run on ``V / s``
    and scaled back gives its usual result bit for bit, on any mesh size.

    Examples
    --------
    >>> import numpy as np
    >>> power_of_two_scale(np.array([[0.0, 0, 0], [3e80, 4e80, 0]])) == 2.0 ** round(np.log2(4e80))
    True
    >>> power_of_two_scale(np.array([[0.0, 0, 0], [3e-300, 1e-300, 0]])) == 2.0 ** round(np.log2(3e-300))
    True
    """
    if V.size == 0:
        return 1.0
    d = float(np.max(V.max(axis=0) - V.min(axis=0)))  # no squares: a norm would overflow at 1e200, underflow at 1e-200
    if not (d > 0 and math.isfinite(d)):
        return 1.0
    return 2.0 ** round(math.log2(d))


def _settings_text(values: dict) -> str:
    """``mu=1e+20, solver='cg'``: the parameters of a run, for messages."""
    return ", ".join(f"{k}={v!r}" for k, v in values.items()) or "no parameters"


class UnknownFilterError(KeyError, ValueError):
    """A filter name that is not registered: a ``ValueError`` (a bad value given to a public function such as
    ``denoise(method=...)``) and, as before, a ``KeyError`` (a failed look-up); the message names the value, the
    closest name and every known one."""

    def __str__(self) -> str:  # the message as written, not KeyError's repr of it
        return str(self.args[0]) if self.args else ""


def get_filter(name: str) -> FilterSpec:
    """The registered filter ``name``; an :class:`UnknownFilterError` (a ``ValueError`` and a ``KeyError``)
    suggests the closest names."""
    _load_plugins()
    if not isinstance(name, str) or name not in REGISTRY:
        hint = difflib.get_close_matches(name, REGISTRY, n=1) if isinstance(name, str) else []
        extra = f" (did you mean '{hint[0]}'?)" if hint else ""
        raise UnknownFilterError(f"unknown filter {name!r}{extra}; known filters: {', '.join(sorted(REGISTRY))}")
    return REGISTRY[name]


def list_filters() -> list[FilterSpec]:
    """Every registered filter, sorted by name."""
    _load_plugins()
    return [REGISTRY[k] for k in sorted(REGISTRY)]


def apply_filter(name: str, mesh: Any, **params) -> Any:
    """Run the registered filter ``name`` on ``mesh`` (any supported mesh type)."""
    return get_filter(name).public(mesh, **params)


_PLUGIN_LOADERS: list[Callable[[], None]] = []


def add_plugin_loader(load: Callable[[], None]) -> Callable[[], None]:
    """Have :func:`get_filter` and :func:`list_filters` call ``load()`` first. The plugins import this module, so it
    names none of them: the package's ``__init__`` (above both) adds the import of :mod:`meshdenoise.plugins`."""
    _PLUGIN_LOADERS.append(load)
    return load


def _load_plugins() -> None:
    for load in _PLUGIN_LOADERS:
        load()
