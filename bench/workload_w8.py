"""W8: periodic voxel homogenization (engine/properties, driver voxlat_homogenize_cell).

(a) Dong, Tang & Zhao (2019) "grid" example: 40^3, struts of radius 0.1 along the cell edges,
    lambda 115.4, mu 79.6. Published: density 0.0855, C11 7.1876, C12 0.3875, C44 0.1489.
(b) A 64^3 gyroid network at ~20% solid: voxlat against the assembled-matrix scipy reference
    (tests/scripts/homogenization_reference.py: assembled K, Jacobi-preconditioned CG to 1e-10;
    its sparse LU needs > 8 GB and > 30 min at this size), side by side. Targets: >= 50x faster,
    C within 1e-4 (largest difference relative to the largest entry).
(c) A 128^3 gyroid network at ~20% solid: time and peak memory. Target: <= 2 GB.
(d) Resolution scaling of the same gyroid at 32^3, 64^3, 128^3 (tolerance 1e-8): CPU time ratio
    against voxel ratio (wall times printed too).
    Target: time grows at most 1.5x faster than the voxel count (per doubling and overall).
(e) Convergence with resolution: the gyroid network at level 0 (density exactly 0.5 at every
    resolution, by symmetry) in a 5 mm cell of Form 2 through `voxlat properties` at 16, 24, 32, 48
    and 64 voxels: E_z and C44 and their successive differences (test
    PropertyDesign.GyroidModulusConvergesWithResolution asserts they shrink).

The cells are written by a separate Python process, so this one stays small: a child's peak
memory as measured includes what it inherited before exec.
"""
import json
import os
import resource
from pathlib import Path

from common import PYTHON, ROOT, measure, row, verdict

TITLE = "W8  homogenization: Dong grid example; 64^3 vs scipy; 128^3 time and memory; scaling 32-128"

REFERENCE = ROOT / "tests/scripts/homogenization_reference.py"
LAMBDA, MU = 115.4, 79.6


def _write_cells(tmp):
    """Writes the cells with the reference module; returns their paths."""
    E = MU * (3 * LAMBDA + 2 * MU) / (LAMBDA + MU)
    nu = LAMBDA / (2 * (LAMBDA + MU))
    paths = {"dong": tmp / "dong40.txt", 32: tmp / "gyroid32.txt", 64: tmp / "gyroid64.txt",
             128: tmp / "gyroid128.txt"}
    script = (f"import sys; sys.path.insert(0, {str(REFERENCE.parent)!r}); import homogenization_reference as r\n"
              f"r.write_cell({str(paths['dong'])!r}, r.grid_cell(40, 0.1), 1.0 / 40, {E!r}, {nu!r})\n"
              f"for n in (32, 64, 128):\n"
              f"    r.write_cell({str(tmp)!r} + f'/gyroid{{n}}.txt', r.gyroid_cell(n, 0.2), 1.0 / n, 1.0, 0.3)\n")
    measure([PYTHON, "-c", script])
    return paths


def _timed(cmd):
    """measure() plus the child's CPU time (user + system): on a shared machine the wall time of
    a program using both cores suffers more than a single-threaded one's."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t, m, out = measure(cmd)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return t, m, out, cpu


def _max_rel_diff(a, b):
    scale = max(abs(v) for r in b for v in r)
    return max(abs(x - y) for ra, rb in zip(a, b) for x, y in zip(ra, rb)) / scale


def run(voxlat, tmp):
    driver = Path(voxlat).parent / "voxlat_homogenize_cell"
    cells = _write_cells(tmp)
    results = {}

    # (a) the published example
    t, m, out = measure([driver, cells["dong"]])
    r = json.loads(out)
    C = r["C"]
    row("Dong grid 40^3 (voxlat)", t, m)
    print(f"  density {r['relative_density']:.4f} (0.0855), C11 {C[0][0]:.4f} (7.1876), C12 {C[0][1]:.4f} (0.3875), "
          f"C44 {C[3][3]:.4f} (0.1489); PCG iterations {r['iterations']}")
    results["dong"] = {"density": r["relative_density"], "C11": C[0][0], "C12": C[0][1], "C44": C[3][3],
                       "seconds": t}

    # (b) 64^3 against the scipy reference
    print(f"  load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    # voxlat at the tolerance `voxlat properties` uses (1e-6, the documented default) and at the
    # driver's tighter 1e-8; both are held to the same 1e-4 agreement with the reference.
    tv, mv, out, cv = _timed([driver, "--tolerance", "1e-6", cells[64]])
    mine = json.loads(out)["C"]
    tt, mt, out, ct = _timed([driver, "--tolerance", "1e-8", cells[64]])
    tight = json.loads(out)["C"]
    tr, mr, out, cr = _timed([PYTHON, REFERENCE, "--cell", cells[64], "--method", "cg"])
    ref = json.loads(out)["C"]
    row("gyroid 64^3 voxlat (tolerance 1e-6, the default)", tv, mv)
    row("gyroid 64^3 voxlat (tolerance 1e-8)", tt, mt)
    row("gyroid 64^3 scipy reference (Jacobi-CG)", tr, mr)
    diff, diff_tight = _max_rel_diff(mine, ref), _max_rel_diff(tight, ref)
    print(f"  speed-up {tr / tv:.0f}x wall (target >= 50x: {verdict(tr / tv >= 50)}), {cr / cv:.0f}x CPU time "
          f"({cv:.2f} s vs {cr:.1f} s); C max difference {diff:.1e} (target <= 1e-4: {verdict(diff <= 1e-4)})")
    print(f"  at tolerance 1e-8: {tr / tt:.0f}x wall, {cr / ct:.0f}x CPU time ({ct:.2f} s), "
          f"C max difference {diff_tight:.1e}")
    print(f"  C11 {mine[0][0]:.6g} vs {ref[0][0]:.6g}, C12 {mine[0][1]:.6g} vs {ref[0][1]:.6g}, "
          f"C44 {mine[3][3]:.6g} vs {ref[3][3]:.6g}")
    results["vs_scipy_64"] = {"voxlat_s": tv, "scipy_s": tr, "speedup": tr / tv, "voxlat_cpu_s": cv,
                              "scipy_cpu_s": cr, "cpu_speedup": cr / cv, "max_rel_diff": diff,
                              "tolerance_1e-8": {"voxlat_s": tt, "speedup": tr / tt, "voxlat_cpu_s": ct,
                                                 "cpu_speedup": cr / ct, "max_rel_diff": diff_tight}}

    # (c) + (d) 128^3, and the scaling
    # All three at the same tolerance (1e-8); growth is judged on CPU time, which a shared
    # machine's changing load (seen: 4 to 10 within one bench run) moves far less than wall time.
    times, peaks, cpus = {64: tt}, {64: mt}, {64: ct}
    for n in (32, 128):
        t, m, out, c = _timed([driver, "--tolerance", "1e-8", cells[n]])
        times[n], peaks[n], cpus[n] = t, m, c
        if n == 128:
            row("gyroid 128^3 voxlat", t, m)
            its = json.loads(out)["iterations"]
            print(f"  peak memory {m:.0f} MB (target <= 2048 MB: {verdict(m <= 2048)}); PCG iterations {its}")
            results["gyroid_128"] = {"seconds": t, "peak_mb": m, "iterations": its}
    row("gyroid 32^3 voxlat", times[32], peaks[32])
    worst = 0.0
    for a, b in ((32, 64), (64, 128), (32, 128)):
        ratio = (cpus[b] / cpus[a]) / (b / a) ** 3
        worst = max(worst, ratio)
        print(f"  {a}^3 -> {b}^3: CPU time x{cpus[b] / cpus[a]:.1f} (wall x{times[b] / times[a]:.1f}) for voxels "
              f"x{(b / a) ** 3:.0f} (time growth / voxel growth {ratio:.2f})")
    print(f"  scaling: worst time growth / voxel growth {worst:.2f} (target <= 1.5: {verdict(worst <= 1.5)}); "
          f"load average {os.getloadavg()[0]:.1f}")
    results["scaling"] = {"seconds": times, "cpu_seconds": cpus, "worst_ratio": worst}

    # (e) convergence with resolution
    recipe = tmp / "gyroid_convergence.yaml"
    recipe.write_text("material: form2\nvoxel: 0.25\ndomain: {box: [[0, 0, 0], [5, 5, 5]]}\nfields:\n"
                      "  lattice: {tpms: gyroid, cell: 5, solid: network, level: 0}\nresult: lattice\n")
    sequence, last = [], None
    print("  convergence (gyroid network, level 0, density 0.5, Form 2):")
    for n in (16, 24, 32, 48, 64):
        out_json = tmp / f"convergence{n}.json"
        t, m, _ = measure([voxlat, "-q", "properties", recipe, "--set", f"properties.resolution={n}",
                           "--json", out_json])
        p = json.loads(out_json.read_text())
        E, G = p["E_MPa"][2], p["C_MPa"][3][3]
        change = "" if last is None else f", change {E - last:+.3f} MPa ({100 * (E - last) / E:+.2f} %)"
        print(f"    {n:3d}^3: E_z {E:.3f} MPa, C44 {G:.3f} MPa, {t:.2f} s{change}")
        sequence.append({"resolution": n, "E_MPa": E, "C44_MPa": G, "seconds": t})
        last = E
    results["convergence"] = sequence
    return results
