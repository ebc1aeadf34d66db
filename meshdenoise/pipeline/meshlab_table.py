"""Regenerate the MeshLab name table (``meshdenoise/pipeline/meshlab_filters.json``) from the installed pymeshlab.

MeshLab's GUI saves filter scripts with MeshLab's names ("Laplacian Smooth",
``stepSmoothNum``); pymeshlab calls the same filter ``apply_coord_laplacian_smoothing``
with ``stepsmoothnum``. pymeshlab exposes no table between the two, but
``MeshSet.save_filter_script`` writes the MeshLab names of the filters applied so far.
So each filter is applied with its defaults to a tiny sphere (or a point cloud, or an
empty MeshSet) in a child process (a few pymeshlab filters abort the process on such
input) and its recorded script is read back::

    python -m meshdenoise.pipeline.meshlab_table -o meshdenoise/pipeline/meshlab_filters.json

The file records the pymeshlab version it came from; :mod:`meshdenoise.pipeline.meshlab_names`
reads it.

Filters needing two meshes, rasters or a GPU cannot be recorded this way and are
absent from the table; :mod:`meshdenoise.pipeline.mlx` then falls back to pymeshlab's
own rule (lower-cased MeshLab names).
"""

from __future__ import annotations

import argparse
import json
import keyword
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET

_CHILD = r"""
import sys, numpy as np, pymeshlab
from meshdenoise.shapes import icosphere
name, path = sys.argv[1], sys.argv[2]
V, F = icosphere(1)
for kind in ("mesh", "points", "empty"):
    ms = pymeshlab.MeshSet()
    if kind == "mesh":
        ms.add_mesh(pymeshlab.Mesh(V, F.astype(np.int32), v_color_matrix=np.full((len(V), 4), 0.5)))
    elif kind == "points":
        ms.add_mesh(pymeshlab.Mesh(V, v_normals_matrix=V))
    try:
        ms.apply_filter(name)
    except Exception:
        continue
    ms.save_filter_script(path)
    break
"""


def record(name: str) -> dict | None:
    """The MeshLab name, parameter names, types and enum labels of pymeshlab filter ``name``, or None."""
    import pymeshlab

    from ..shapes import icosphere

    with tempfile.TemporaryDirectory() as tmp:
        path = f"{tmp}/f.mlx"
        try:
            subprocess.run([sys.executable, "-c", _CHILD, name, path], capture_output=True, timeout=120)
            filters = ET.parse(path).getroot().findall("filter")
        except (OSError, ET.ParseError, subprocess.TimeoutExpired):
            return None
    if not filters:
        return None
    node = filters[-1]
    V, F = icosphere(1)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(V, F.astype("int32")))
    by_lower = {p.get("name").lower(): p for p in node.findall("Param")}
    params = {}
    for py in ms.filter_parameter_values(name):
        key = py[:-1] if py.endswith("_") and keyword.iskeyword(py[:-1]) else py
        p = by_lower[key]
        entry = {"name": p.get("name"), "type": p.get("type")}
        if entry["type"] == "RichEnum":
            entry["enum"] = [p.get(f"enum_val{i}") for i in range(int(p.get("enum_cardinality")))]
        params[py] = entry
    return {"meshlab": node.get("name"), "params": params}


def to_json(table: dict, version: str) -> str:
    """The table file's text: one filter per line, sorted, so that a regeneration diffs by filter."""
    lines = [
        "{",
        ' "comment": "MeshLab names, parameters, types and enum labels of pymeshlab filters, recorded with '
        "pymeshlab's own save_filter_script; one filter per line. Regenerate: python -m meshdenoise.pipeline.meshlab_table "
        '-o meshdenoise/pipeline/meshlab_filters.json",',
        f' "pymeshlab_version": {json.dumps(version)},',
        ' "filters": {',
    ]
    items = sorted(table.items())
    for k, (name, entry) in enumerate(items):
        lines.append("  " + json.dumps(name) + ": " + json.dumps(entry, sort_keys=True) + ("," if k < len(items) - 1 else ""))
    lines += [" }", "}"]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    from importlib.metadata import version

    import pymeshlab

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default=None, help="write here (default: stdout)")
    args = parser.parse_args(argv)
    table = {}
    for name in pymeshlab.filter_list():
        entry = record(name)
        if entry is not None:
            table[name] = entry
        print(f"{name}: {'ok' if entry else 'not recorded'}", file=sys.stderr)
    print(json.dumps({"recorded": len(table)}), file=sys.stderr)
    text = to_json(table, version("pymeshlab"))
    if args.output:
        with open(args.output, "w", encoding="utf-8") as f:
            f.write(text)
    else:
        sys.stdout.write(text)


if __name__ == "__main__":
    main()
