"""Filter families, one module each. Importing this package registers every filter.

Each module registers its filters with :func:`meshdenoise.registry.register`: the array
core, its :class:`~meshdenoise.registry.Param` list and its automatic rule
(:class:`~meshdenoise.registry.AutoRule`). A new filter is one new module, named after
the filter it registers, added to ``MODULES`` below (tests/test_code_layout.py
checks that every module of this folder is listed).
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
