"""W2g: strut lattices that are not boxes of identical cells (issue 17), where voxlat evaluates
strut by strut, each side by side with the seed paper's method in numpy/scipy on the same struts
(bench/reference/w2_numpy_convolution.py --frame; each strut weighted for its radius at its middle:
the method's cost depends on the struts, not on their weights):

- graded: the W2 frame (BCC 5 mm, sigma 0.5, 20 %, 50 mm cube, 0.1 mm) with
  `radius: {gradient: linear, min: 0.3, max: 0.7, axis: z}` (target >= 50x, peak <= 1.5 GB);
- centred: the same frame with radii graded from the centre outwards, as issue 38 words it
  (`radius: {gradient: centred, min: 0.3, max: 0.7}`: |2u - 1| along x; target >= 50x);
- trimmed: the same BCC cells `within:` a cylinder (radius 25, the cube's height), struts cut at
  its surface (IntraLattice's rule, min_length 0.5 mm, as voxlat's clippedFrame);
- cylinder: a cylinder frame of BCC cells (radius 25, inner 10, height 50; 10 axial, 24 angular,
  3 radial cells) in the box [-26, 26]^2 x [0, 50];
- wireframe: 97 336 struts read from a CSV file (`struts: {wireframe: ...}`): 23^3 BCC cells
  on the 50 mm cube with every node moved by up to 0.1 cell per axis, so nothing repeats
  (the issue's wireframe of 1e5 struts; target >= 50x). First run, 2026-11-29 (issue 38, third
  round), VOXLAT_W2G_SIZE=25 (13 824 struts) at load 16-25: voxlat 486.6 s (solve 332.0 s,
  evaluate 146.2 s), 202 MB, vs numpy 679.7 s, 458 MB: 1.4x (target 50x: missed; the density
  solve and the evaluation of a frame that nothing folds are the cost).

The frames are built here the way engine/frames/StrutFrames.cpp builds them and handed to the
reference as arrays; the strut counts of both sides are printed. VOXLAT_W2G_SIZE=25 runs the
graded and trimmed cases on a 25 mm cube (and the cylinder at half size) for a quick look.

Profile (perf, graded frame, before issue 17's work): StrutConvolution::gridValues 60-64 % of the
run, segmentBoxDistance 3 %, IsoRadius 2-3 %, the index's gather/sort 3 %; the density solve (a
sparse pass on a lattice 1.16x finer than the voxels) cost twice the final evaluation; bounds
cull well already (about 75 % of the evaluated leaves hold the surface). Tried and dropped:
culling 4^3 quarters of straddling leaves by their bounds (only a third of the quarters cull, no
net gain) and a tighter bound using I0 near joints (leaves 5721 -> 5715). Kept: rows take only
the points inside a strut's capsule (same bits, about 10 %); radii graded linearly along one axis
fold the other two axes (PeriodicTiling and periodicPieces with period 0 along the graded axis;
CPU time of the graded frame about 60 s -> 10 s); table blocks evaluated on first use.
Measured (side by side, 2 shared cores at load average 10-11, so both sides ran ~8x slow): graded
66.3 s vs 1043 s (15.7x, target 50x missed), peak 943 MB; trimmed 84.7 s vs 556 s (6.6x);
cylinder 70.0 s vs 250 s (3.6x). Quiet machine (load 0.6): graded 7.21 s vs 274 s (38.0x),
peak 943 MB (evaluate 2.17 s, solve 1.99 s, mesh 1.58 s, pieces 0.91 s, STL 0.30 s).
Trimmed (quiet): 29.3 s vs 225 s (7.7x; evaluate 9.2 s, solve 17.1 s); cylinder 25.2 s vs 189 s
(7.5x; evaluate 8.1 s, solve 14.8 s). W2 in that run: 52.3x at 0.1 mm (peak 905 MB), 21.2x at 0.2 mm. W1 in the same quiet run:
3.62 s vs 17.55 s (4.9x; target 10x missed).
After the pieces count on leaf bit masks, huge pages and the streamed density count (graded case
only, side by side at load 7 falling to 4.5): 19.38 s vs 667.1 s (34.4x, target 50x missed),
peak 952 MB (evaluate 5.89 s, solve 5.49 s, mesh 3.62 s, STL 2.93 s, pieces 0.69 s).
2026-11-27 (quiet, load 1.0-1.1), after the AVX2 row loop (fields/StrutRowsAvx2.cpp, same
doubles), the density pieces' in-period mirror (one half of each part of the period, counted
twice: solve 2.73 -> 1.16 s) and the tiling table's mirror and 8^3 bricks (evaluate 1.9 -> 1.4 s):
graded 4.01 s vs 232.7 s (58.0x, target met), peak 581 MB (solve 1.16 s, evaluate 1.39 s, mesh +
STL 1.09 s, pieces 0.20 s); trimmed 31.2 s vs 201.2 s (6.4x; evaluate 11.6 s, solve 18.2 s);
cylinder 28.4 s vs 158.3 s (5.6x; evaluate 10.5 s, solve 16.0 s). Earlier the same day, before
these: graded 4.94 s vs 249.5 s (50.5x) with only the solve's mirror, 5.29-6.75 s (31-46x) before.
With the density pieces' x-y swap too (18 421 -> 12 644 leaves): graded 4.09 s vs 177.3 s (43.4x:
the STL stage 1.88 s, stalled behind the reference's writeback; bench/common.py now syncs before
every timed run) and 3.16 s vs 198.7 s (62.9x; solve 0.60 s, evaluate 1.00 s, mesh + STL 1.26 s).
2026-11-29 (issue 38, second round): the recipes now say `allow: [pieces]`: since the pieces check
the graded frame (sigma 0.5 at 20 %) stops with 2 222 pieces (joints left where struts vanish),
and the reference counts none. VOXLAT_W2G_SIZE=25 at load 16-18 (the machine shared by six
agents; ratios of wall times): graded 11.85 s vs 174.6 s (14.7x), trimmed 44.0 s vs 81.5 s (1.9x;
solve 28.7 s, evaluate 14.1 s), cylinder 51.8 s vs 256.5 s (5.0x; solve 31.4 s, evaluate 19.4 s);
peaks 168-349 MB. Target 50x each: missed; the trimmed and cylinder frames spend most of their
time in the density solve.
2026-11-29 (issue 38, fifth round, branch issue38e; bench/history.md): the aim's evaluation at a
moved level reuses the raw values (GridValueMemo) and the coverage solve's band is grown by the
coarse step near its bracket. VOXLAT_W2G_SIZE=25 at load 8-13, main / branch / numpy side by side:
trimmed 33.78 / 25.98 / 94.23 s (2.79x -> 3.63x), cylinder 108.74 / 99.63 / 210.42 s (1.94x ->
2.11x), wireframe 389.2 / 412.2 / 1004.3 s (2.58x -> 2.44x: the same leaves both, noise). Same STL bytes. Target 50x each: missed.
Trimmed at 50 mm, main and branch only (a fair pair at load 5-7): 107.2 s -> 70.6 s wall, 62.6 s ->
44.8 s CPU, peak 2853 -> 2076 MB (target 1.5 GB: missed); solve 52.3 -> 37.2 s.
2026-11-30 (issue 38, eighth round, branch issue38h; bench/history.md): the centred case added; the
solve's wider band reads its first pass's leaves, a solve on the recipe's lattice keeps its raw
values for the grid, rows load table nodes without gathers, centred radii fold like linear ones.
VOXLAT_W2G_SIZE=25 at load 3.6-7.0, main / branch / numpy side by side: graded 0.96 / 0.99 / 23.58 s
(24.4x / 23.7x), centred 16.88 / 3.79 / 23.75 s (1.41x -> 6.27x), trimmed 9.86 / 7.34 / 22.67 s
(2.30x -> 3.09x), wireframe 85.9 / 93.6 / 135.9 s (1.58x / 1.45x: load; -10 % CPU in an A/B),
cylinder 44.27 / 27.68 / 48.20 s (1.09x -> 1.74x). Target 50x each: missed.
2026-12-01 (issue 38, seventeenth round, branch issue38u; bench/history.md): general frames
evaluated and solved in stacks of eight leaves along z, row tables for struts steep to the rows.
VOXLAT_W2G_SIZE=25 at load 3.0-3.5, branch / main (numpy in each run): trimmed 1.92 / 3.01 s (4.3x /
3.3x), wireframe 8.48 / 18.10 s (6.0x / 3.0x), cylinder 3.37 / 5.57 s (5.4x / 3.0x); graded and
centred the same code (5.9-8.9x, the load); at load 2.0-1.2: trimmed 0.96 / 1.36 s (8.3x / 5.7x),
wireframe 4.38 / 8.87 s (12.6x / 5.9x), cylinder 1.94 / 3.07 s (8.8x / 5.6x). Target 50x each: missed.
2026-12-02 (issue 38, twenty-first round; bench/history.md): the memo's values as floats and the
solve's grid kept for the mesh. At 50 mm, quiet: graded 119.9x, centred 110.3x, trimmed 35.0x (988 MB),
wireframe 36.2x (1225 MB), cylinder 28.1x (871 MB): peak 1.5 GB met on every frame, 50x missed on
trimmed, wireframe and cylinder.
2026-12-07 (issue 38, fortieth round; bench/history.md): frames that nothing tiles take their grids
from exact nodes every second voxel (fields/struts/CoarseNodes, within a proven bound) where sigma
spans four voxels or more. At 50 mm, two runs: trimmed 27.9x / 29.4x, wireframe 46.5x / 49.5x
(9.91 s against 490.35 s), cylinder 21.4x / 23.6x (the thirty-ninth round's 25.6-26.5x, 26.2x,
14.6-17.8x); graded 56.0x / 50.8x and centred 52.2x / 46.0x (their paths unchanged); peak <= 1014 MB.
"""
import json
import math
import os

import numpy as np

from common import LAST_CPU, PYTHON, ROOT, cpu_text, measure, row, verdict

TITLE = ("W2g BCC convolution lattices off the periodic path (graded radii, trimmed, cylinder frame, "
         "a 1e5-strut wireframe) vs numpy")

SIGMA = 0.5
CELL = 5.0
RMIN, RMAX = 0.3, 0.7


def bcc_struts(lo, counts, cell):
    struts = []
    for i in range(counts[0]):
        for j in range(counts[1]):
            for k in range(counts[2]):
                for dx in (0, 1):
                    for dy in (0, 1):
                        for dz in (0, 1):
                            struts.append(((i + 0.5, j + 0.5, k + 0.5), (i + dx, j + dy, k + dz)))
    return [(np.array(lo) + np.array(a) * cell, np.array(lo) + np.array(b) * cell) for a, b in struts]


def jittered(struts, cell, amount, seed=38):
    """The struts with every node moved by up to @a amount cells per axis (one move per node, so
    struts that share a node still meet): a wireframe no periodic path can fold."""
    rng = np.random.default_rng(seed)
    moves = {}

    def move(p):
        key = tuple(np.round(np.asarray(p) / cell * 2).astype(int))
        if key not in moves:
            moves[key] = rng.uniform(-amount, amount, 3) * cell
        return np.asarray(p) + moves[key]

    return [(move(a), move(b)) for a, b in struts]


def cylinder_sdf(p, centre, radius, height):
    """voxlat's capped cylinder along z (signed distance; <= 0 inside)."""
    dr = math.hypot(p[0] - centre[0], p[1] - centre[1]) - radius
    dz = abs(p[2] - centre[2]) - 0.5 * height
    out = math.hypot(max(dr, 0.0), max(dz, 0.0))
    return out + min(max(dr, dz), 0.0)


def trimmed(struts, inside, min_length):
    """clippedFrame: keep inside struts, cut crossing ones by bisection, IntraLattice's rule."""
    kept = []
    for a, b in struts:
        ina, inb = inside(a) <= 0.0, inside(b) <= 0.0
        if not ina and not inb:
            continue
        if ina and inb:
            kept.append((a, b))
            continue
        if not ina:
            a, b = b, a
        lo, hi = 0.0, 1.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if inside(a + mid * (b - a)) <= 0.0:
                lo = mid
            else:
                hi = mid
        length = np.linalg.norm(b - a)
        if lo * length < min_length:
            continue
        kept.append((a, b) if length - lo * length < min_length else (a, a + lo * (b - a)))
    return kept


def cylinder_bcc(radius, inner, height, cells, base):
    axial, angular, radial = cells

    def m(u):
        r = inner + u[0] / radial * (radius - inner)
        th = u[1] / angular * 2 * math.pi
        return np.array([base[0] + r * math.cos(th), base[1] + r * math.sin(th), base[2] + u[2] / axial * height])

    seen, struts = set(), []
    for a, b in bcc_struts((0, 0, 0), (radial, angular, axial), 1.0):
        pa, pb = m(a), m(b)
        key = tuple(sorted((tuple(np.round(pa, 6)), tuple(np.round(pb, 6)))))
        if key in seen or np.linalg.norm(pb - pa) == 0:
            continue
        seen.add(key)
        struts.append((pa, pb))
    return struts


LINEAR_Z = f"{{gradient: linear, min: {RMIN}, max: {RMAX}, axis: z}}"
# The wording: radii graded from the centre outwards (`centred`: |2u - 1| along x, u running
# 0 to 1 over the frame's box).
CENTRED = f"{{gradient: centred, min: {RMIN}, max: {RMAX}}}"


def weights(struts, lo, hi, centred=False):
    """Per strut: the weight of voxlat's radius gradient at the strut's middle (linear along z, or
    centred along x)."""
    out = []
    axis = 0 if centred else 2
    for a, b in struts:
        u = (0.5 * (a[axis] + b[axis]) - lo[axis]) / (hi[axis] - lo[axis])
        r = RMIN + (abs(2 * u - 1) if centred else u) * (RMAX - RMIN)
        out.append(math.exp(r * r / (2 * SIGMA * SIGMA)) / (SIGMA * math.sqrt(2 * math.pi)))
    return np.array(out)


def case(voxlat, tmp, name, struts_yaml, box, struts, target, radius=LINEAR_Z):
    lo, hi = box
    recipe = tmp / f"{name}.yaml"
    recipe.write_text(f"voxel: 0.1\ndomain: {{box: [{list(lo)}, {list(hi)}]}}\nfields:\n"
                      f"  lattice: {{struts: {struts_yaml}, kernel: {{gaussian: {{sigma: {SIGMA}}}}}, radius: {radius}, "
                      f"density: 0.20}}\nresult: lattice\nallow: [pieces]\noutputs: {{mesh: {name}.stl}}\n")
    t_v, m_v, _ = measure([voxlat, "-q", "run", recipe, "--out", tmp / name, "--no-preview"])
    cpu = dict(LAST_CPU)  # the reference's run below replaces LAST_CPU
    report = json.loads((tmp / name / "report.json").read_text())
    frame = np.array([[a, b] for a, b in struts])
    np.save(tmp / f"{name}-frame.npy", frame)
    flo = [min(frame[:, :, a].min(), lo[a]) for a in range(3)]
    fhi = [max(frame[:, :, a].max(), lo[a]) for a in range(3)]
    np.save(tmp / f"{name}-w.npy", weights(struts, flo, fhi, radius == CENTRED))
    t_r, m_r, out_r = measure([PYTHON, ROOT / "bench/reference/w2_numpy_convolution.py", "--frame",
                               tmp / f"{name}-frame.npy", "--weights", tmp / f"{name}-w.npy", "--box",
                               *lo, *hi, "--out", tmp / f"{name}-ref.stl"])
    (tmp / f"{name}-ref.stl").unlink()
    print(f" {name}: {len(struts)} struts (reference frame)")
    row("voxlat", t_v, m_v)
    row("numpy/scipy/skimage, dense grid", t_r, m_r)
    ratio = t_r / t_v
    goal = f" (target >= {target}x: {verdict(ratio >= target)})" if target else ""
    print(f"  speed-up {ratio:.1f}x{goal}; voxlat peak {m_v:.0f} MB (target <= 1536 MB: {verdict(m_v <= 1536)})")
    print(f"  voxlat: density {report['fields']['lattice']['achieved_density']:.5f}, "
          f"{report['mesh']['triangles']} triangles; reference: {' | '.join(out_r.strip().splitlines()[-2:])}")
    print("  voxlat stages: " + ", ".join(f"{k} {v:.2f}s" for k, v in report["timings_s"].items()))
    print(f"  voxlat CPU: {cpu_text(cpu)}")
    return {"voxlat_s": t_v, "reference_s": t_r, "ratio": ratio, "voxlat_mb": m_v, "reference_mb": m_r,
            "struts": len(struts), "voxlat_user_s": cpu["user"], "voxlat_system_s": cpu["system"]}


def run(voxlat, tmp):
    size = float(os.environ.get("VOXLAT_W2G_SIZE", "50"))
    # VOXLAT_W2G_CASES=graded (a comma list) runs only those cases.
    only = set(os.environ.get("VOXLAT_W2G_CASES", "graded,centred,trimmed,cylinder,wireframe").split(","))
    n = int(round(size / CELL))
    print(f"  load average before: {os.getloadavg()[0]:.2f}")
    out = {}
    box = ((0.0, 0.0, 0.0), (size, size, size))
    if "graded" in only:
        out["graded"] = case(voxlat, tmp, "graded", f"{{cell: bcc, size: {CELL:g}}}", box,
                             bcc_struts(box[0], (n, n, n), CELL), 50)
    if "centred" in only:
        out["centred"] = case(voxlat, tmp, "centred", f"{{cell: bcc, size: {CELL:g}}}", box,
                              bcc_struts(box[0], (n, n, n), CELL), 50, radius=CENTRED)
    c, rad = (0.5 * size, 0.5 * size, 0.5 * size), 0.5 * size
    bcc = bcc_struts(box[0], (n, n, n), CELL)
    if "trimmed" in only:
        out["trimmed"] = case(voxlat, tmp, "trimmed",
                              f"{{cell: bcc, size: {CELL:g}, within: {{cylinder: {{center: {list(c)}, radius: {rad:g}, "
                              f"height: {size:g}}}}}}}", box,
                              trimmed(bcc, lambda p: cylinder_sdf(p, c, rad, size), 0.1 * CELL), 50)
    s = size / 50.0
    cyl = dict(radius=25 * s, inner=10 * s, height=50 * s, cells=(max(1, n), 24, 3))
    cbox = ((-26 * s, -26 * s, 0.0), (26 * s, 26 * s, 50 * s))
    if "wireframe" in only:
        # About 1e5 struts (23^3 jittered BCC cells on the 50 mm cube) read from a CSV file.
        nw = max(1, int(round(size * 23 / 50)))
        wcell = size / nw
        wire = jittered(bcc_struts(box[0], (nw, nw, nw), wcell), wcell, 0.1)
        with open(tmp / "wireframe.csv", "w") as f:
            f.write("x1,y1,z1,x2,y2,z2\n")
            for a, b in wire:
                f.write(",".join(f"{v:.6f}" for v in (*a, *b)) + "\n")
        out["wireframe"] = case(voxlat, tmp, "wireframe", f"{{wireframe: {tmp / 'wireframe.csv'}}}", box, wire, 50)
    if "cylinder" in only:
        out["cylinder"] = case(voxlat, tmp, "cylinder",
                               f"{{cell: bcc, cylinder: {{radius: {cyl['radius']:g}, inner: {cyl['inner']:g}, "
                               f"height: {cyl['height']:g}, cells: {list(cyl['cells'])}}}}}", cbox,
                               cylinder_bcc(cyl["radius"], cyl["inner"], cyl["height"], cyl["cells"], (0.0, 0.0, 0.0)),
                               50)
    print(f"  load average after: {os.getloadavg()[0]:.2f}")
    return out
