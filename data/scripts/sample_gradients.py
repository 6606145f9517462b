#!/usr/bin/env python3
"""Query a recipe's field anywhere: values and exact gradients on numpy arrays, compared with
numpy's own gyroid. Uses data/recipes/gyroid.yaml with its density solved at a coarse voxel.

    PYTHONPATH=build/python python3 data/scripts/sample_gradients.py
"""
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "build" / "python"))
import voxlat  # noqa: E402

recipe = voxlat.Recipe.load(ROOT / "data/recipes/gyroid.yaml", sets=["voxel=0.5"])
job = recipe.job()
job.solve()
level = job.report()["fields"]["lattice"]["level"]
field = job.field("lattice")

t = np.linspace(0, 50, 10001)
points = np.stack([t, 0.3 * t, 25 + 0 * t], axis=1)
values, gradients = field.gradients(points)
k = 2 * np.pi / 10
x, y, z = (k * points[:, i] for i in range(3))
expected = np.sin(x) * np.cos(y) + np.sin(y) * np.cos(z) + np.sin(z) * np.cos(x) - level
print(f"level {level:.6f}; max |value - numpy| = {np.max(np.abs(values - expected)):.2e}; "
      f"mean |gradient| = {np.mean(np.linalg.norm(gradients, axis=1)):.4f} per mm")
inside = np.count_nonzero(values < 0)
print(f"{inside} of {len(t)} samples on the line are inside the lattice")
