#!/usr/bin/env python3
"""W1 reference: the acceptance gyroid done with OpenVDB's own tools on a dense grid.

numpy gyroid on the full 500^3 grid, the level as a quantile of the dense values,
pyopenvdb copyFromArray + convertToPolygons, binary STL written with numpy. This is the
straightforward pipeline a user of OpenVDB's Python module writes today.
"""
import argparse
import sys

import numpy as np
import pyopenvdb as vdb


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=float, default=50.0)
    ap.add_argument("--voxel", type=float, default=0.1)
    ap.add_argument("--cell", type=float, default=10.0)
    ap.add_argument("--density", type=float, default=0.30)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()

    n = int(round(a.size / a.voxel))
    x = ((np.arange(n, dtype=np.float32) + 0.5) * a.voxel * (2 * np.pi / a.cell)).astype(np.float32)
    sx, cx = np.sin(x), np.cos(x)
    # f = sin X cos Y + sin Y cos Z + sin Z cos X on the dense grid (float32, broadcast).
    f = sx[:, None, None] * cx[None, :, None] + sx[None, :, None] * cx[None, None, :]
    f += sx[None, None, :] * cx[:, None, None]
    level = float(np.quantile(f, a.density))  # network: f <= level fills `density`
    achieved = float(np.count_nonzero(f <= level)) / f.size

    # Cap the solid at the domain: pad with an outside layer.
    padded = np.full((n + 2, n + 2, n + 2), level + 1.0, dtype=np.float32)
    padded[1:-1, 1:-1, 1:-1] = f
    del f
    grid = vdb.FloatGrid(background=level + 1.0)
    grid.copyFromArray(padded, ijk=(-1, -1, -1), tolerance=0)
    del padded
    xform = vdb.createLinearTransform(voxelSize=a.voxel)
    xform.translate((0.5 * a.voxel,) * 3)
    grid.transform = xform
    points, triangles, quads = grid.convertToPolygons(isovalue=level, adaptivity=0.0)
    tris = np.concatenate([triangles, quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]).astype(np.int64)

    record = np.zeros(len(tris), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    v = points.astype(np.float32)[tris]
    nrm = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-30)[:, None]
    record["n"] = nrm
    record["v"] = v
    with open(a.out, "wb") as fh:
        fh.write(b"numpy binary STL".ljust(80, b" "))
        fh.write(np.uint32(len(tris)).tobytes())
        fh.write(record.tobytes())
    print(f"level {level:.6f} achieved {achieved:.5f} triangles {len(tris)}", file=sys.stderr)


if __name__ == "__main__":
    main()
