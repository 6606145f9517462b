#!/usr/bin/env python3
"""Writes bracket.stl: an L-bracket (30 x 24 x 24 mm, 5 mm plates) with a 3 mm fillet in the
inner corner and four 5 mm through holes, two in each plate. The mesh is built face by face so
that it is closed, manifold and outward oriented with about two thousand triangles (binary STL,
~100 KB), the way a CAD export looks, rather than the millions a voxel mesher would give.

    python3 data/meshes/make_bracket.py [output.stl]
"""
import math
import struct
import sys
from collections import defaultdict, deque
from pathlib import Path

L, W, H, T = 30.0, 24.0, 24.0, 5.0  # length (x), base width (y), height (z), plate thickness
FILLET, FILLET_SEGMENTS = 3.0, 8
HOLE_R, HALF_CELL, K = 2.5, 4.0, 8  # hole radius, half the square around a hole, segments per side
HOLE_X = (7.5, 22.5)
HOLE_Y = 16.0  # base holes (vertical), centre across the base
HOLE_Z = 16.0  # upright holes (along y), centre up the upright

# The L profile in the (y, z) plane, counter-clockwise seen from +x, with extra points where the
# squares around the holes begin and end. Each entry: (y, z).
arc = [(T + FILLET + FILLET * math.cos(a), T + FILLET + FILLET * math.sin(a))
       for a in (math.radians(270 - 90 * i / FILLET_SEGMENTS) for i in range(FILLET_SEGMENTS + 1))]
profile = ([(0.0, 0.0), (HOLE_Y - HALF_CELL, 0.0), (HOLE_Y + HALF_CELL, 0.0), (W, 0.0), (W, T),
            (HOLE_Y + HALF_CELL, T), (HOLE_Y - HALF_CELL, T)] + arc[:-1] +
           [(T, T + FILLET), (T, HOLE_Z - HALF_CELL), (T, HOLE_Z + HALF_CELL), (T, H), (0.0, H),
            (0.0, HOLE_Z + HALF_CELL), (0.0, HOLE_Z - HALF_CELL)])
xs = sorted({0.0, L} | {x + d for x in HOLE_X for d in (-HALF_CELL, HALF_CELL)})

# Hole cells: (profile edge index, x interval index).
def edge_index(a, b):
    return next(i for i in range(len(profile)) if profile[i] == a and profile[(i + 1) % len(profile)] == b)

hole_edges = {
    edge_index((HOLE_Y - HALF_CELL, 0.0), (HOLE_Y + HALF_CELL, 0.0)): "base",
    edge_index((HOLE_Y + HALF_CELL, T), (HOLE_Y - HALF_CELL, T)): "base",
    edge_index((T, HOLE_Z - HALF_CELL), (T, HOLE_Z + HALF_CELL)): "upright",
    edge_index((0.0, HOLE_Z + HALF_CELL), (0.0, HOLE_Z - HALF_CELL)): "upright",
}
hole_x_intervals = {xs.index(x - HALF_CELL) for x in HOLE_X}
hole_cells = {(e, j) for e in hole_edges for j in hole_x_intervals}

vertices, index = [], {}


def vid(p):
    key = tuple(round(c, 9) for c in p)
    if key not in index:
        index[key] = len(vertices)
        vertices.append(key)
    return index[key]


triangles = []


def point(x, e, v):
    """x along the bracket, position v in [0, 1] along profile edge e."""
    (y0, z0), (y1, z1) = profile[e], profile[(e + 1) % len(profile)]
    return (x, y0 + v * (y1 - y0), z0 + v * (z1 - z0))


def segments(a, b):
    return K if a in hole_cells or b in hole_cells else 1


n = len(profile)
for e in range(n):
    for j in range(len(xs) - 1):
        x0, x1 = xs[j], xs[j + 1]
        sides = [segments((e, j), ((e - 1) % n, j)),      # v = 0 (shared with the previous edge)
                 segments((e, j), (e, j + 1)),             # u = 1
                 segments((e, j), ((e + 1) % n, j)),       # v = 1
                 segments((e, j), (e, j - 1))]             # u = 0
        loop = []  # (u, v) around the cell
        for s in range(sides[0]): loop.append((s / sides[0], 0.0))
        for s in range(sides[1]): loop.append((1.0, s / sides[1]))
        for s in range(sides[2]): loop.append((1 - s / sides[2], 1.0))
        for s in range(sides[3]): loop.append((0.0, 1 - s / sides[3]))
        pts = [point(x0 + u * (x1 - x0), e, v) for u, v in loop]
        ids = [vid(p) for p in pts]
        if (e, j) in hole_cells:
            c = point(0.5 * (x0 + x1), e, 0.5)
            ring = []
            for p in pts:
                d = [p[i] - c[i] for i in range(3)]
                r = math.sqrt(sum(t * t for t in d))
                ring.append(vid(tuple(c[i] + HOLE_R * d[i] / r for i in range(3))))
            for s in range(len(ids)):
                a, b = ids[s], ids[(s + 1) % len(ids)]
                ra, rb = ring[s], ring[(s + 1) % len(ids)]
                triangles += [(a, b, rb), (a, rb, ra)]
        elif len(ids) == 4:
            triangles += [(ids[0], ids[1], ids[2]), (ids[0], ids[2], ids[3])]
        else:
            c = vid(point(0.5 * (x0 + x1), e, 0.5))
            triangles += [(ids[s], ids[(s + 1) % len(ids)], c) for s in range(len(ids))]

# Hole walls: the circle points of a hole, sorted by angle, joined between the two plates' faces.
for x in HOLE_X:
    for kind in ("base", "upright"):
        if kind == "base":
            circle = sorted({(vv[0], vv[1]) for vv in vertices
                             if vv[2] == 0.0 and abs(math.hypot(vv[0] - x, vv[1] - HOLE_Y) - HOLE_R) < 1e-6},
                            key=lambda p: math.atan2(p[1] - HOLE_Y, p[0] - x))
            a_ids = [index[(p[0], p[1], 0.0)] for p in circle]
            b_ids = [index[(p[0], p[1], T)] for p in circle]
        else:
            circle = sorted({(vv[0], vv[2]) for vv in vertices
                             if vv[1] == 0.0 and abs(math.hypot(vv[0] - x, vv[2] - HOLE_Z) - HOLE_R) < 1e-6},
                            key=lambda p: math.atan2(p[1] - HOLE_Z, p[0] - x))
            a_ids = [index[(p[0], 0.0, p[1])] for p in circle]
            b_ids = [index[(p[0], T, p[1])] for p in circle]
        for s in range(len(circle)):
            t = (s + 1) % len(circle)
            triangles += [(a_ids[s], a_ids[t], b_ids[t]), (a_ids[s], b_ids[t], b_ids[s])]

# End caps: ear clipping of the profile (it has collinear points; strict ears only).
def cross(o, a, b):
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def inside(p, a, b, c):
    return cross(a, b, p) >= 0 and cross(b, c, p) >= 0 and cross(c, a, p) >= 0


remaining, ears = list(range(n)), []
while len(remaining) > 3:
    for i in range(len(remaining)):
        a, b, c = remaining[i - 1], remaining[i], remaining[(i + 1) % len(remaining)]
        if cross(profile[a], profile[b], profile[c]) <= 1e-12:
            continue
        if any(inside(profile[o], profile[a], profile[b], profile[c]) for o in remaining if o not in (a, b, c)):
            continue
        ears.append((a, b, c))
        remaining.pop(i)
        break
    else:
        sys.exit("ear clipping failed")
ears.append(tuple(remaining))
for x in (0.0, L):
    for a, b, c in ears:
        triangles.append(tuple(vid((x,) + profile[q]) for q in (a, b, c)))

# Orientation: make neighbours agree, then make the enclosed volume positive.
edge_tris = defaultdict(list)
for t, tri in enumerate(triangles):
    for k in range(3):
        edge_tris[frozenset((tri[k], tri[(k + 1) % 3]))].append(t)
assert all(len(v) == 2 for v in edge_tris.values()), "mesh is not closed and manifold"
tris = [list(t) for t in triangles]
seen = [False] * len(tris)
for seed in range(len(tris)):
    if seen[seed]:
        continue
    seen[seed] = True
    queue = deque([seed])
    while queue:
        t = queue.popleft()
        for k in range(3):
            a, b = tris[t][k], tris[t][(k + 1) % 3]
            for o in edge_tris[frozenset((a, b))]:
                if o == t or seen[o]:
                    continue
                if any(tris[o][m] == a and tris[o][(m + 1) % 3] == b for m in range(3)):
                    tris[o][1], tris[o][2] = tris[o][2], tris[o][1]
                seen[o] = True
                queue.append(o)


def volume(ts):
    s = 0.0
    for a, b, c in ts:
        p, q, r = vertices[a], vertices[b], vertices[c]
        s += (p[0] * (q[1] * r[2] - q[2] * r[1]) - p[1] * (q[0] * r[2] - q[2] * r[0]) +
              p[2] * (q[0] * r[1] - q[1] * r[0]))
    return s / 6.0


if volume(tris) < 0:
    tris = [[a, c, b] for a, b, c in tris]

out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_name("bracket.stl")
with open(out, "wb") as f:
    f.write(b"voxlat bracket: L 30x24x24 mm, 5 mm plates, 3 mm fillet, 4 holes".ljust(80, b" "))
    f.write(struct.pack("<I", len(tris)))
    for a, b, c in tris:
        p, q, r = vertices[a], vertices[b], vertices[c]
        u = [q[i] - p[i] for i in range(3)]
        v = [r[i] - p[i] for i in range(3)]
        nrm = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
        ln = math.sqrt(sum(t * t for t in nrm)) or 1.0
        f.write(struct.pack("<12fH", *(t / ln for t in nrm), *p, *q, *r, 0))
print(f"{out}: {len(tris)} triangles, {len(vertices)} vertices, volume {volume(tris):.2f} mm3")
