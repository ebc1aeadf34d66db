"""Filter families, one module each. Importing this package registers every filter.

Each module registers its filters with :func:`meshdenoise.registry.register`: the array
core, its :class:`~meshdenoise.registry.Param` list and its automatic rule
(:class:`~meshdenoise.registry.AutoRule`), whose choice functions live in a module of their own next
to it, ``<filter>_rule`` (``sobolev_gls_rule``), which the filter's module imports and which does not
import it back (it reaches the filter through ``get_filter(name)``). A new filter is one new module,
named after the filter it registers, added to ``MODULES`` below (tests/test_code_layout.py
checks that every module of this folder is listed, or is a listed filter's rule). A module whose name
starts with ``_`` holds parts of one family that its filter and its rule share, and registers nothing
(``_gls_solve``: ``sobolev_gls``' settings and its solves; ``_averaging``: the averaging matrices of
``filtering`` and ``taubin``).

Each filter's settings (the sizes and bounds that choose its solve paths) are a frozen object: in the
filter's module when only its core reads them (``SobolevConfig``), in its rule's when only the rule does
(``SinkhornConfig``, ``TaubinConfig``), in the family's underscore module when both do (``GlsConfig``,
``AxesConfig``, ``SobolevNormalConfig``; the filter's module exports them too). Its array core takes
``config=`` (``get_filter(name).core(V, F, ops=..., pinned=None, config=..., **params)``) and its rule
reads the one handed to ``choose_parameters(..., config=...)``.
"""

from . import (  # noqa: F401  (imported for their registrations)
    filtering,
    heat,
    sinkhorn,
    sobolev,
    sobolev_axes,
    sobolev_bilaplacian,
    sobolev_gls,
    sobolev_normal,
    taubin,
    two_stage,
)

MODULES = (
    "filtering",
    "heat",
    "sinkhorn",
    "sobolev",
    "sobolev_axes",
    "sobolev_bilaplacian",
    "sobolev_gls",
    "sobolev_normal",
    "taubin",
    "two_stage",
)
