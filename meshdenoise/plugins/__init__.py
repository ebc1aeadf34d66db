"""Filter families, one module each. Importing this package registers every filter."""

from . import filtering, heat, sobolev  # noqa: F401
