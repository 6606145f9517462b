"""W8: periodic voxel homogenization (engine/properties, driver voxlat_homogenize_cell).

(a) Dong, Tang & Zhao (2019) "grid" example: 40^3, struts of radius 0.1 along the cell edges,
    lambda 115.4, mu 79.6. Published: density 0.0855, C11 7.1876, C12 0.3875, C44 0.1489.
(b) A 64^3 gyroid network at ~20% solid: voxlat against the assembled-matrix scipy reference
    (tests/scripts/homogenization_reference.py: assembled K, Jacobi-preconditioned
    CG to 1e-10; its sparse LU needs > 8 GB and > 30 min at this size), side by side. Targets: >= 50x faster,
    C within 1e-4 (largest difference relative to the largest entry).
(c) A 128^3 gyroid network at ~20% solid: time and peak memory. Target: <= 2 GB.
(d) Resolution scaling of the same gyroid at 32^3, 64^3, 128^3: time ratio against voxel ratio.
    Target: time grows at most 1.5x faster than the voxel count (per doubling and overall).
"""
import json
import sys

from common import PYTHON, ROOT, measure, row, verdict

sys.path.insert(0, str(ROOT / "tests" / "scripts"))
import homogenization_reference as reference  # noqa: E402

TITLE = "W8  homogenization: Dong grid example; 64^3 vs scipy; 128^3 time and memory; scaling 32-128"

LAMBDA, MU = 115.4, 79.6


def _grid_cell(n, r):
    import numpy as np
    c = (np.arange(n) + 0.5) / n
    d = np.minimum(c, 1 - c)
    z, y, x = np.meshgrid(d, d, d, indexing="ij")
    return (y * y + z * z < r * r) | (x * x + z * z < r * r) | (x * x + y * y < r * r)


def _driver(voxlat):
    from pathlib import Path
    return Path(voxlat).parent / "voxlat_homogenize_cell"


def run(voxlat, tmp):
    import numpy as np
    driver = _driver(voxlat)
    results = {}

    # (a) the published example
    E = MU * (3 * LAMBDA + 2 * MU) / (LAMBDA + MU)
    nu = LAMBDA / (2 * (LAMBDA + MU))
    path = tmp / "dong40.txt"
    reference.write_cell(path, _grid_cell(40, 0.1), 1.0 / 40, E, nu)
    t, m, out = measure([driver, path])
    r = json.loads(out)
    C = r["C"]
    row("Dong grid 40^3 (voxlat)", t, m)
    print(f"  density {r['relative_density']:.4f} (0.0855), C11 {C[0][0]:.4f} (7.1876), C12 {C[0][1]:.4f} (0.3875), "
          f"C44 {C[3][3]:.4f} (0.1489); PCG iterations {r['iterations']}")
    results["dong"] = {"density": r["relative_density"], "C11": C[0][0], "C12": C[0][1], "C44": C[3][3],
                       "seconds": t}

    # (b) 64^3 against the scipy reference
    E, nu = 1.0, 0.3
    cells = {}
    for n in (32, 64, 128):
        cells[n] = tmp / f"gyroid{n}.txt"
        reference.write_cell(cells[n], reference.gyroid_cell(n, 0.2), 1.0 / n, E, nu)
    tv, mv, out = measure([driver, cells[64]])
    mine = np.array(json.loads(out)["C"])
    tr, mr, out = measure([PYTHON, ROOT / "tests/scripts/homogenization_reference.py", "--cell", cells[64],
                           "--method", "cg"])
    ref = np.array(json.loads(out)["C"])
    row("gyroid 64^3 voxlat", tv, mv)
    row("gyroid 64^3 scipy reference (Jacobi-CG)", tr, mr)
    diff = np.abs(mine - ref).max() / np.abs(ref).max()
    print(f"  speed-up {tr / tv:.0f}x (target >= 50x: {verdict(tr / tv >= 50)}); C max difference {diff:.1e} "
          f"(target <= 1e-4: {verdict(diff <= 1e-4)})")
    print(f"  C11 {mine[0, 0]:.6g} vs {ref[0, 0]:.6g}, C12 {mine[0, 1]:.6g} vs {ref[0, 1]:.6g}, "
          f"C44 {mine[3, 3]:.6g} vs {ref[3, 3]:.6g}")
    results["vs_scipy_64"] = {"voxlat_s": tv, "scipy_s": tr, "speedup": tr / tv, "max_rel_diff": diff}

    # (c) + (d) 128^3, and the scaling
    times, iterations = {64: tv}, {}
    for n in (32, 128):
        t, m, out = measure([driver, cells[n]])
        times[n] = t
        iterations[n] = json.loads(out)["iterations"]
        if n == 128:
            row("gyroid 128^3 voxlat", t, m)
            print(f"  peak memory {m:.0f} MB (target <= 2048 MB: {verdict(m <= 2048)}); PCG iterations "
                  f"{iterations[n]}")
            results["gyroid_128"] = {"seconds": t, "peak_mb": m, "iterations": iterations[n]}
    row("gyroid 32^3 voxlat", times[32], 0)
    worst = 0.0
    for a, b in ((32, 64), (64, 128), (32, 128)):
        ratio = (times[b] / times[a]) / (b / a) ** 3
        worst = max(worst, ratio)
        print(f"  {a}^3 -> {b}^3: time x{times[b] / times[a]:.1f} for voxels x{(b / a) ** 3:.0f} "
              f"(time growth / voxel growth {ratio:.2f})")
    print(f"  scaling: worst time growth / voxel growth {worst:.2f} (target <= 1.5: {verdict(worst <= 1.5)})")
    results["scaling"] = {"seconds": times, "worst_ratio": worst}
    return results
