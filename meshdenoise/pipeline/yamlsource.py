"""YAML documents whose mappings and lists remember the line of every key and item.

Error messages of a pipeline name the file and line; PyYAML's composer knows the marks
of every node, so a loader that copies them onto the constructed containers is enough.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from .errors import PipelineValidationError

__all__ = ["LineDict", "LineList", "load_yaml", "line_of"]


class LineDict(dict):
    """A dict with ``line`` (its own first line) and ``key_lines`` (1-based line of each key)."""

    line: int = 0
    key_lines: dict


class LineList(list):
    """A list with ``line`` and ``item_lines`` (1-based line of each item)."""

    line: int = 0
    item_lines: list


class _Loader(yaml.SafeLoader):
    pass


def _mapping(loader: _Loader, node: yaml.MappingNode) -> LineDict:
    loader.flatten_mapping(node)
    out = LineDict()
    out.line = node.start_mark.line + 1
    out.key_lines = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if not isinstance(key, (str, int, float, bool)) and key is not None:
            raise PipelineValidationError(f"{loader.name}:{key_node.start_mark.line + 1}: a key must be a name, got {key!r}")
        if key in out:
            raise PipelineValidationError(
                f"{loader.name}:{key_node.start_mark.line + 1}: key {key!r} appears twice "
                f"(first on line {out.key_lines[key]})"
            )
        out[key] = loader.construct_object(value_node, deep=True)
        out.key_lines[key] = key_node.start_mark.line + 1
    return out


def _sequence(loader: _Loader, node: yaml.SequenceNode) -> LineList:
    out = LineList(loader.construct_object(child, deep=True) for child in node.value)
    out.line = node.start_mark.line + 1
    out.item_lines = [child.start_mark.line + 1 for child in node.value]
    return out


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping)
_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_SEQUENCE_TAG, _sequence)


def load_yaml(text: str, name: str | Path = "<string>") -> Any:
    """Parse one YAML document; syntax errors become :class:`PipelineValidationError` with file and line."""
    loader = _Loader(text)
    loader.name = str(name)
    try:
        return loader.get_single_data()
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = f":{mark.line + 1}" if mark is not None else ""
        raise PipelineValidationError(f"{name}{line}: not valid YAML: {exc.problem or exc}") from None
    except yaml.YAMLError as exc:
        raise PipelineValidationError(f"{name}: not valid YAML: {exc}") from None
    finally:
        loader.dispose()


def line_of(container: Any, key: Any = None) -> int | None:
    """The line of ``container[key]`` (or of the container itself), when known."""
    if key is None:
        return getattr(container, "line", None)
    if isinstance(container, LineDict):
        return container.key_lines.get(key, container.line)
    if isinstance(container, LineList) and isinstance(key, int) and 0 <= key < len(container.item_lines):
        return container.item_lines[key]
    return getattr(container, "line", None)
