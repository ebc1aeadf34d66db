"""YAML documents whose mappings and lists remember the line of every key and item.

Error messages of a pipeline name the file and line; PyYAML's composer knows the marks
of every node, so a loader that copies them onto the constructed containers is enough.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from .errors import PipelineValidationError

__all__ = ["LineDict", "LineList", "NumberLoader", "load_yaml", "read_text", "line_of", "MAX_NODES", "MAX_DEPTH", "MAX_BYTES"]

#: Limits of a pipeline document, checked before it is built: values counted with every ``*alias``
#: expanded (a few bytes of anchors can stand for billions of values), nesting depth, and file size.
MAX_NODES = 200_000
MAX_DEPTH = 64
MAX_BYTES = 10_000_000

_BOMS = ((b"\xef\xbb\xbf", "utf-8-sig"), (b"\xff\xfe\x00\x00", "utf-32"), (b"\x00\x00\xfe\xff", "utf-32"),
         (b"\xff\xfe", "utf-16"), (b"\xfe\xff", "utf-16"))


class LineDict(dict):
    """A dict with ``line`` (its own first line) and ``key_lines`` (1-based line of each key)."""

    line: int = 0
    key_lines: dict


class LineList(list):
    """A list with ``line`` and ``item_lines`` (1-based line of each item)."""

    line: int = 0
    item_lines: list


class NumberLoader(yaml.SafeLoader):
    """PyYAML's safe loader whose numbers are decimal numbers as Python writes them, read by
    :func:`meshdenoise.registry.parse_number` (the one number reader of the command line and pipelines).

    ``1e-3`` and ``2E5`` are floats (YAML 1.2; YAML 1.1 wants a dot), ``010`` is 10 and ``1_000`` is 1000
    (Python's ``int()``). YAML 1.1's other number forms are not numbers here but text, which a numeric
    parameter then refuses: octal ``010`` (8), ``0x10`` (16), ``0b11`` (3) and base 60 ``1:30`` (90).
    ``.inf`` and ``.nan`` stay floats (a parameter refuses them: it must be finite).
    """


_INT_TAG, _FLOAT_TAG = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"
_DIGITS = r"[0-9](?:_?[0-9])*"  # Python's digitpart: underscores only between digits
#: Scalars read as numbers: what Python's ``int()`` and ``float()`` read, in decimal (and YAML's ``.inf``, ``.nan``).
DECIMAL_INT = re.compile(rf"^[-+]?{_DIGITS}$")
DECIMAL_FLOAT = re.compile(
    rf"^(?:[-+]?(?:(?:(?:{_DIGITS})?\.{_DIGITS}|{_DIGITS}\.)(?:[eE][-+]?{_DIGITS})?|{_DIGITS}[eE][-+]?{_DIGITS})"
    r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"
)
NumberLoader.yaml_implicit_resolvers = {  # YAML 1.1's int and float rules out, ours in
    first: [(tag, regexp) for tag, regexp in rules if tag not in (_INT_TAG, _FLOAT_TAG)]
    for first, rules in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
NumberLoader.add_implicit_resolver(_INT_TAG, DECIMAL_INT, list("-+0123456789"))
NumberLoader.add_implicit_resolver(_FLOAT_TAG, DECIMAL_FLOAT, list("-+0123456789."))


def _construct_number(kind: type):
    def construct(loader: yaml.SafeLoader, node: yaml.ScalarNode) -> int | float:
        from ..registry import parse_number

        text = loader.construct_scalar(node)
        special = text.strip().lower().lstrip("+")
        if kind is float and special in (".inf", "-.inf", ".nan"):
            return float(special.replace(".", ""))
        try:
            return parse_number(text, kind)
        except (TypeError, ValueError, OverflowError) as exc:  # an explicit !!int 0x10
            raise yaml.constructor.ConstructorError(None, None, f"{text!r} is not a decimal number ({exc})",
                                                    node.start_mark) from None

    return construct


NumberLoader.add_constructor(_INT_TAG, _construct_number(int))
NumberLoader.add_constructor(_FLOAT_TAG, _construct_number(float))


class _Loader(NumberLoader):
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


def read_text(path: str | Path) -> str:
    """The text of a pipeline file: UTF-8, or UTF-8/16/32 with a byte-order mark.

    Raises
    ------
    PipelineValidationError
        Anything else (Latin-1, UTF-16 without a byte-order mark, binary data), naming the
        file, the byte offset and the line of the first undecodable byte; or a file larger
        than :data:`MAX_BYTES`.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_BYTES:
            raise PipelineValidationError(f"{path}: {size} bytes; a pipeline file is at most {MAX_BYTES} bytes")
        data = path.read_bytes()
    except OSError as exc:
        raise PipelineValidationError(f"{path}: cannot be read: {exc.strerror or exc}") from None
    encoding = next((enc for bom, enc in _BOMS if data.startswith(bom)), "utf-8")
    try:
        text = data.decode(encoding)
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise PipelineValidationError(
            f"{path}:{line}: not {encoding.replace('-sig', '')} text: byte 0x{data[exc.start]:02x} at byte offset "
            f"{exc.start} ({exc.reason}); save the file as UTF-8"
        ) from None
    nul = text.find("\x00")
    if nul >= 0:
        offset = len(text[:nul].encode(encoding.replace("-sig", ""))) if encoding == "utf-8" else nul
        line = text.count("\n", 0, nul) + 1
        raise PipelineValidationError(
            f"{path}:{line}: a NUL byte at byte offset {offset}: not a text file "
            "(UTF-16 without a byte-order mark?); save the file as UTF-8"
        )
    return text.lstrip("\ufeff")


def _check_size(node: yaml.Node, name: str) -> None:
    """Refuse a document with more than MAX_NODES values (aliases expanded), deeper than MAX_DEPTH, or recursive."""
    size: dict[int, int] = {}
    height: dict[int, int] = {}
    state: dict[int, int] = {}  # 1: being expanded (an ancestor), 2: done

    def children(n):
        if isinstance(n, yaml.SequenceNode):
            return n.value
        if isinstance(n, yaml.MappingNode):
            return [x for pair in n.value for x in pair]
        return []

    stack = [(node, False)]
    while stack:
        n, done = stack.pop()
        k = id(n)
        if done:
            kids = children(n)
            size[k] = 1 + sum(size[id(c)] for c in kids)
            height[k] = 1 + max((height[id(c)] for c in kids), default=0)
            state[k] = 2
            line = n.start_mark.line + 1
            if size[k] > MAX_NODES:
                raise PipelineValidationError(
                    f"{name}:{line}: this value expands to {size[k]} values (aliases counted), more than the limit {MAX_NODES}"
                )
            if height[k] > MAX_DEPTH:
                raise PipelineValidationError(f"{name}:{line}: nested more than {MAX_DEPTH} levels deep")
            continue
        if state.get(k) == 2:
            continue
        if state.get(k) == 1:
            raise PipelineValidationError(f"{name}:{n.start_mark.line + 1}: a value contains itself (a recursive alias)")
        state[k] = 1
        stack.append((n, True))
        stack.extend((c, False) for c in children(n) if state.get(id(c)) != 2)


def load_yaml(text: str, name: str | Path = "<string>") -> Any:
    """Parse one YAML document; syntax errors become :class:`PipelineValidationError` with file and line.

    The document is checked against :data:`MAX_NODES` and :data:`MAX_DEPTH` before it is built.
    """
    try:
        loader = _Loader(text)  # the reader checks the characters here
    except yaml.YAMLError as exc:
        raise PipelineValidationError(f"{name}: not valid YAML: {exc}") from None
    loader.name = str(name)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check_size(node, str(name))
        return loader.construct_document(node)
    except RecursionError:
        raise PipelineValidationError(f"{name}: nested too deeply (more than {MAX_DEPTH} levels)") from None
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
