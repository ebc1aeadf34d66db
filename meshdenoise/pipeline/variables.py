"""``${name}`` variables in pipeline parameters, and ``--set name=value`` overrides.

A value that is exactly ``${mu}`` takes the variable's value with its type (a number
stays a number); ``${mu}`` inside a longer string is replaced by its text.
"""

from __future__ import annotations

import difflib
import re
from typing import Any

import yaml

from .errors import PipelineValidationError
from .yamlsource import LineDict, LineList, NumberLoader

__all__ = ["substitute", "parse_assignment", "check_template", "used_variables", "VARIABLE", "MAX_FIELD_WIDTH"]

#: Largest width or precision allowed in a ``{name:>8}`` placeholder of an output path.
MAX_FIELD_WIDTH = 255
_FORMAT_SPEC = re.compile(r"(?:.?[<>=^])?[+\- ]?z?#?0?(?P<width>\d+)?[_,]?(?:\.(?P<precision>\d+))?[bcdeEfFgGnosxX%]?", re.S)

VARIABLE = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}")


def parse_assignment(text: str) -> tuple[str, Any]:
    """``"mu=5"`` -> ``("mu", 5)``: the value is read as YAML (numbers, booleans, lists).

    >>> parse_assignment("mu=0.5"), parse_assignment("name=a b"), parse_assignment("mu=1e-3")
    (('mu', 0.5), ('name', 'a b'), ('mu', 0.001))
    """
    if "=" not in text:
        raise ValueError(f"expected NAME=VALUE, got {text!r}")
    name, _, raw = text.partition("=")
    name = name.strip()
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise ValueError(f"{text!r}: {name!r} is not a variable name (letters, digits, _)")
    try:
        value = yaml.load(raw, Loader=NumberLoader) if raw.strip() else ""  # noqa: S506 (a safe loader)
    except yaml.YAMLError:
        value = raw
    return name, value


def check_template(template: str) -> None:
    """Refuse a path template whose placeholders are more than ``{name}`` or ``{name:format}``.

    Only plain names are allowed (no ``{0}``, ``{stem.attr}``, ``{stem[0]}``, ``{stem!r}``), and a
    format's width and precision are at most :data:`MAX_FIELD_WIDTH`: ``{stem:>99999999999}``
    would otherwise try to build a string of 100 GB. Checked before anything is formatted.

    Raises
    ------
    ValueError
        Naming the placeholder and the rule.

    >>> check_template("{stem}_{mu:.3g}.ply")
    >>> check_template("{stem:>99999999999}.ply")
    Traceback (most recent call last):
    ...
    ValueError: path template '{stem:>99999999999}.ply': placeholder {stem:>99999999999}: width 99999999999 is more than 255
    """
    import string

    try:
        parts = list(string.Formatter().parse(template))
    except ValueError as exc:  # a lone { or }
        raise ValueError(f"path template {template!r}: {exc} (write {{{{ and }}}} for literal braces)") from None
    for _, name, spec, conversion in parts:
        if name is None:
            continue
        shown = "{" + name + (f"!{conversion}" if conversion else "") + (f":{spec}" if spec else "") + "}"
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
            raise ValueError(f"path template {template!r}: placeholder {shown}: only plain names like {{stem}} are allowed")
        if conversion:
            raise ValueError(f"path template {template!r}: placeholder {shown}: conversions (!r, !s) are not allowed")
        m = _FORMAT_SPEC.fullmatch(spec or "")
        if m is None:
            raise ValueError(f"path template {template!r}: placeholder {shown}: {spec!r} is not a format like >8 or .3g")
        for what in ("width", "precision"):
            if m.group(what) and int(m.group(what)) > MAX_FIELD_WIDTH:
                raise ValueError(
                    f"path template {template!r}: placeholder {shown}: {what} {int(m.group(what))} is more than {MAX_FIELD_WIDTH}"
                )


def substitute(value: Any, variables: dict, where: str) -> Any:
    """A copy of ``value`` (nested dicts/lists) with every ``${name}`` replaced; line information kept."""
    if isinstance(value, str):
        whole = VARIABLE.fullmatch(value.strip())
        if whole:
            return _lookup(whole.group(1), variables, where)
        return VARIABLE.sub(lambda m: str(_lookup(m.group(1), variables, where)), value)
    if isinstance(value, dict):
        # Keys too: a sweep may choose the step itself (``- ${method}: {}``).
        out = LineDict((substitute(k, variables, where) if isinstance(k, str) else k, substitute(v, variables, where)) for k, v in value.items())
        out.line = getattr(value, "line", 0)
        lines = getattr(value, "key_lines", {})
        out.key_lines = {substitute(k, variables, where) if isinstance(k, str) else k: v for k, v in lines.items()}
        return out
    if isinstance(value, list):
        out = LineList(substitute(v, variables, where) for v in value)
        out.line = getattr(value, "line", 0)
        out.item_lines = getattr(value, "item_lines", [])
        return out
    return value


def used_variables(value: Any) -> set[str]:
    """The names of every ``${name}`` in ``value`` (nested dicts and lists, keys too).

    >>> sorted(used_variables({"steps": [{"sobolev": {"mu": "${mu}"}}, {"${method}": {}}], "x": "a${b}c"}))
    ['b', 'method', 'mu']
    """
    found: set[str] = set()
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            found.update(VARIABLE.findall(item))
        elif isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
    return found


def _lookup(name: str, variables: dict, where: str) -> Any:
    if name not in variables:
        hint = difflib.get_close_matches(name, list(variables), n=1)
        extra = f" (did you mean '{hint[0]}'?)" if hint else ""
        known = ", ".join(sorted(variables)) or "none"
        raise PipelineValidationError(
            f"{where}: undefined variable '${{{name}}}'{extra}; defined: {known} "
            "(define it under 'variables:' or pass --set NAME=VALUE)"
        )
    return variables[name]
