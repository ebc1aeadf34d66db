"""mesh_info against pymeshlab's topological measures and a per-vertex loop written for the test."""

import numpy as np
import pymeshlab
from click.testing import CliRunner

from meshdenoise.cli import cli
from meshdenoise.io import save_mesh
from meshdenoise.meshinfo import mesh_info
from meshdenoise.shapes import grid, icosphere


def _fans_loop(F, v):
    faces = [f for f in F if v in f]
    comp = list(range(len(faces)))
    for i in range(len(faces)):
        for j in range(i):
            if len(set(faces[i]) & set(faces[j])) >= 2:
                a, b = comp[i], comp[j]
                comp = [b if c == a else c for c in comp]
    return len(set(comp))


def test_mesh_info_matches_pymeshlab_and_loop():
    V, F = icosphere(2)
    # two spheres glued at one vertex, a boundary hole, an extra duplicate vertex
    V2 = V + [2.0, 0, 0]
    V2[0] = V[0]  # same position as vertex 0
    F2 = F + len(V)
    F2[F2 == len(V)] = 0  # share vertex 0: non-manifold vertex
    VV = np.vstack([V, V2, V[:1] + 5])
    FF = np.vstack([F, F2[3:]])
    info = mesh_info(VV, FF)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(VV, FF.astype(np.int32)))
    t = ms.get_topological_measures()
    assert info["boundary_edges"] == t["boundary_edges"]
    assert info["non_manifold_edges"] == t["non_two_manifold_edges"]
    assert info["non_manifold_vertices"] == t["non_two_manifold_vertices"] == sum(_fans_loop(FF, v) > 1 for v in range(len(VV)))
    assert info["unreferenced_vertices"] == t["unreferenced_vertices"] == 2
    assert info["connected_components"] == 1 and info["boundary_loops"] == 1 and info["duplicate_vertices"] == len(VV) - len({tuple(p) for p in VV.tolist()})


def test_info_command(tmp_path):
    V, F = grid(4, 3)
    save_mesh(tmp_path / "g.off", V, F)
    result = CliRunner().invoke(cli, ["info", str(tmp_path / "g.off"), "--json"])
    assert result.exit_code == 0 and '"boundary_loops": 1' in result.output
    assert CliRunner().invoke(cli, ["info", str(tmp_path / "no.off")]).exit_code == 2
