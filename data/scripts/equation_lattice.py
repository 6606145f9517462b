#!/usr/bin/env python3
"""A lattice from your own equation, with parameters: a gyroid whose cells grow along z, cut at
25 % density; the mesh as numpy arrays, written as PLY and OBJ.

    PYTHONPATH=build/python python3 data/scripts/equation_lattice.py [OUT_DIR]
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "build" / "python"))
import voxlat  # noqa: E402

out = Path(sys.argv[1] if len(sys.argv) > 1 else "out")
out.mkdir(parents=True, exist_ok=True)

# Cell size c(z) = $c0 * (1 + $grow * z / 20): the phase 2*pi*x/c(z) keeps the surface smooth.
graded = voxlat.expr("sin(2*pi*x/(${c0}*(1 + $grow*z/20)))*cos(2*pi*y/(${c0}*(1 + $grow*z/20)))"
                     " + sin(2*pi*y/(${c0}*(1 + $grow*z/20)))*cos(2*pi*z/(${c0}*(1 + $grow*z/20)))"
                     " + sin(2*pi*z/(${c0}*(1 + $grow*z/20)))*cos(2*pi*x/(${c0}*(1 + $grow*z/20)))")
recipe = voxlat.Recipe(graded.network(density=0.25), domain=[[0, 0, 0], [20, 20, 20]], voxel=0.2,
                       params={"c0": 5, "grow": 0.5})
job = recipe.job(sets=["grow=0.8"])
points, triangles = job.mesh()
job.write_mesh(str(out / "graded.ply"))
job.write_mesh(str(out / "graded.obj"))
lo, hi = points.min(axis=0), points.max(axis=0)
print(f"{len(triangles)} triangles within {np.round(lo, 2)} .. {np.round(hi, 2)} mm; "
      f"level {job.report()['fields']['result']['level']:.4f}")
