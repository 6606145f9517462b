#!/usr/bin/env python3
"""W3 reference: the mesh-first route to resin slices a user has today.

The acceptance gyroid sheet (|f| <= 0.3, 8 mm cells, 60 x 60 x 30 mm) is sampled on a dense
0.1 mm grid, meshed by scikit-image's marching cubes (capped at the domain by intersecting with
the box), written as a binary STL, and sliced for a Prusa SL1S by PrusaSlicer's command line
(`--export-sla`) with supports, pad, closing radius, elephant-foot and corrections off and the
first layer as thick as the others (shared/reference/lattice-reference.md section 5).

  w3_mesh_prusaslicer.py mesh --out part.stl      # step 1 (python)
  w3_mesh_prusaslicer.py config --out sl1s.ini    # the PrusaSlicer config used by step 2
"""
import argparse
import sys

import numpy as np

SL1S_INI = """printer_technology = SLA
printer_model = SL1S
printer_variant = default
printer_settings_id = Original Prusa SL1S SPEED
bed_shape = 0x0,128x0,128x81,0x81
display_width = 128
display_height = 81
display_pixels_x = 2560
display_pixels_y = 1620
display_mirror_x = 1
display_mirror_y = 0
display_orientation = portrait
gamma_correction = 1
max_print_height = 150
area_fill = 45
fast_tilt_time = 2.5
slow_tilt_time = 5
layer_height = {layer}
initial_layer_height = {layer}
exposure_time = 2
initial_exposure_time = 30
faded_layers = 10
supports_enable = 0
pad_enable = 0
hollowing_enable = 0
slice_closing_radius = 0
elefant_foot_compensation = 0
absolute_correction = 0
relative_correction = 1,1
printer_correction = 1,1,1
material_correction = 1,1,1
"""


def gyroid_sheet(x, y, z, cell, level):
    k = 2 * np.pi / cell
    X, Y, Z = k * x, k * y, k * z
    return np.abs(np.sin(X) * np.cos(Y) + np.sin(Y) * np.cos(Z) + np.sin(Z) * np.cos(X)) - level


def mesh(a):
    from skimage.measure import marching_cubes

    n = [int(round(s / a.voxel)) for s in a.size]
    # Voxel centres plus one outside layer, so the solid is capped where it meets the domain.
    axes = [((np.arange(-1, m + 1, dtype=np.float32) + 0.5) * a.voxel) for m in n]
    k = np.float32(2 * np.pi / a.cell)
    s = [np.sin(k * t) for t in axes]
    c = [np.cos(k * t) for t in axes]
    f = s[0][:, None, None] * c[1][None, :, None] + s[1][None, :, None] * c[2][None, None, :]
    f += s[2][None, None, :] * c[0][:, None, None]
    np.abs(f, out=f)
    f -= np.float32(a.level)
    # Intersect with the box (a signed distance per axis, max over axes).
    for axis, (t, size) in enumerate(zip(axes, a.size)):
        d = np.maximum(-t, t - size).astype(np.float32)
        shape = [1, 1, 1]
        shape[axis] = len(t)
        np.maximum(f, d.reshape(shape), out=f)
    verts, faces, _, _ = marching_cubes(f, 0.0, spacing=(a.voxel,) * 3, allow_degenerate=False)
    del f
    verts = verts.astype(np.float32) + np.float32(-0.5 * a.voxel)  # index 0 is the outside layer at -voxel/2
    tri = verts[faces]
    del verts, faces
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    # skimage orients normals towards increasing values (outside); STL wants outward: keep.
    record = np.zeros(len(tri), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    record["n"] = nrm / np.maximum(np.linalg.norm(nrm, axis=1), 1e-30)[:, None]
    record["v"] = tri
    with open(a.out, "wb") as out:
        out.write(b"voxlat W3 reference".ljust(80, b"\0"))
        out.write(np.uint32(len(tri)).tobytes())
        record.tofile(out)
    print(f"{len(tri)} triangles")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("step", choices=["mesh", "config"])
    ap.add_argument("--size", type=float, nargs=3, default=[60.0, 60.0, 30.0])
    ap.add_argument("--voxel", type=float, default=0.1)
    ap.add_argument("--cell", type=float, default=8.0)
    ap.add_argument("--level", type=float, default=0.3)
    ap.add_argument("--layer", type=float, default=0.05)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    if a.step == "mesh":
        mesh(a)
    else:
        with open(a.out, "w") as out:
            out.write(SL1S_INI.format(layer=a.layer))


if __name__ == "__main__":
    sys.exit(main())
