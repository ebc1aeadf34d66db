"""Write the small meshes this project makes itself (run from the repository root: python meshes/make_meshes.py).

They are generated, not downloaded: `tests/test_project_meshes.py` checks that the files
equal what this script writes, so they cannot drift from `meshdenoise.shapes`.
"""

from pathlib import Path

from meshdenoise.io import save_mesh
from meshdenoise.shapes import box, grid, icosphere, torus

HERE = Path(__file__).resolve().parent

MESHES = {
    "sphere.ply": lambda: icosphere(3),  # 642 vertices, closed, smooth
    "torus.ply": lambda: torus(48, 24),  # 1,152 vertices, closed, genus 1
    "box.ply": lambda: box(12),  # 866 vertices, closed, sharp edges and corners
    "plane.off": lambda: grid(24, 24),  # 576 vertices, open: a boundary to pin
}


def main(folder: Path = HERE) -> list[Path]:
    return [save_mesh(folder / name, *make()) for name, make in MESHES.items()]


if __name__ == "__main__":
    for path in main():
        print(path)
