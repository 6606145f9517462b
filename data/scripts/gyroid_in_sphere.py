#!/usr/bin/env python3
"""Build a part from Python: a gyroid sheet at 20 % density inside a sphere. Saves the recipe
(so `voxlat run` can re-make it), writes the mesh, prints its size.

    PYTHONPATH=build/python python3 data/scripts/gyroid_in_sphere.py [OUT_DIR]
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "build" / "python"))
import voxlat  # noqa: E402

out = Path(sys.argv[1] if len(sys.argv) > 1 else "out")
out.mkdir(parents=True, exist_ok=True)

part = voxlat.gyroid(cell=6).sheet(density=0.2) & voxlat.sphere(radius=14, center=[15, 15, 15])
recipe = voxlat.Recipe(part, domain=[[0, 0, 0], [30, 30, 30]], voxel=0.2, outputs={"mesh": "gyroid_sphere.stl"})
recipe.save(out / "gyroid_sphere.yaml")
report = recipe.run(out)
points, triangles = recipe.mesh()
print(f"{len(triangles)} triangles, {len(points)} vertices, "
      f"density {report['fields']['result/1']['achieved_density']:.4f}, recipe sha256 {report['recipe_sha256'][:12]}")
