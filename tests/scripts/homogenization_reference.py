#!/usr/bin/env python3
"""An independent reference for engine/properties/Homogenization: periodic voxel homogenization by
an assembled sparse stiffness matrix (scipy), written straight from Andreassen & Andreasen (2014)
and Dong, Tang & Zhao (2019), sharing no code or conventions beyond the definition of C^H.

    C^H_ij = 1/|Y| sum_e (u0_i - chi_i)_e^T ke (u0_j - chi_j)_e,   K chi_i = F_i

with one isoparametric 8-node hexahedron per solid voxel (nodes in the counter-clockwise order of
Dong et al., xi in [-1, 1]^3), DOFs of all grid points (periodic: point i of an axis of n is
point i mod n), the loads integrated directly from B^T C eps0, and islands and non-percolating
directions left in: both carry zero energy in the exact solution, so they must come out zero here
without the special handling the C++ core has.

The singular system (rigid translations per component, and more) is solved: a minimum-norm
least-squares solve for small systems, fixing one node per connected component plus a tiny
diagonal shift and a sparse LU for larger ones (the shift moves C^H by ~1e-12), and
Jacobi-preconditioned CG to a relative residual of 1e-10 for large ones.

As a test (ctest homogenization_reference): compares voxlat_homogenize_cell with this on small
cells (gyroid-like, random with islands and corner contacts, odd sizes, thermal) to 1e-6.
"""
import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as spla

# Dong et al.'s node order: (x, y, z) corners of [-1, 1]^3.
CORNERS = np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
                    [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], dtype=float)


def _gauss_points():
    g = 1.0 / np.sqrt(3.0)
    return [(a, b, c) for a in (-g, g) for b in (-g, g) for c in (-g, g)]


def _shape_gradients(xi, h):
    """dN/dx (8 x 3) at reference point xi of a box element of size h (3,)."""
    dn = np.zeros((8, 3))
    for a, (cx, cy, cz) in enumerate(CORNERS):
        nx, ny, nz = 1 + cx * xi[0], 1 + cy * xi[1], 1 + cz * xi[2]
        dn[a] = [cx * ny * nz / 8, nx * cy * nz / 8, nx * ny * cz / 8]
    return dn * (2.0 / np.asarray(h))  # d xi / dx = 2 / h


def _b_matrix(dn):
    """Strain-displacement matrix, Voigt xx, yy, zz, yz, xz, xy with engineering shear."""
    B = np.zeros((6, 24))
    for a in range(8):
        dx, dy, dz = dn[a]
        B[0, 3 * a] = dx
        B[1, 3 * a + 1] = dy
        B[2, 3 * a + 2] = dz
        B[3, 3 * a + 1], B[3, 3 * a + 2] = dz, dy
        B[4, 3 * a], B[4, 3 * a + 2] = dz, dx
        B[5, 3 * a], B[5, 3 * a + 1] = dy, dx
    return B


def isotropic(E, nu):
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    C = np.zeros((6, 6))
    C[:3, :3] = lam
    C[np.arange(3), np.arange(3)] += 2 * mu
    C[np.arange(3, 6), np.arange(3, 6)] = mu
    return C


def element_elastic(h, E, nu):
    """ke (24 x 24) and fe (24 x 6: loads of the six unit strains), by 2x2x2 Gauss."""
    C = isotropic(E, nu)
    detJ = np.prod(h) / 8.0
    ke, fe = np.zeros((24, 24)), np.zeros((24, 6))
    for xi in _gauss_points():
        B = _b_matrix(_shape_gradients(xi, h))
        ke += B.T @ C @ B * detJ
        fe += B.T @ C * detJ
    return ke, fe, C


def element_thermal(h, k):
    detJ = np.prod(h) / 8.0
    ke, fe = np.zeros((8, 8)), np.zeros((8, 3))
    for xi in _gauss_points():
        G = _shape_gradients(xi, h).T  # 3 x 8
        ke += G.T @ G * k * detJ
        fe += G.T * k * detJ
    return ke, fe, k * np.eye(3)


def _unit_fields(h, dofs_per_node):
    """Nodal values of the unit macroscopic fields on one element (8*D x cases)."""
    x = (CORNERS + 1) / 2 * np.asarray(h)  # node coordinates, origin at the element corner
    if dofs_per_node == 1:
        return x.copy()  # temperature x_i for gradient i
    u = np.zeros((24, 6))
    for case in range(6):
        eps = np.zeros((3, 3))
        if case < 3:
            eps[case, case] = 1
        else:
            i, j = [(1, 2), (0, 2), (0, 1)][case - 3]
            eps[i, j] = eps[j, i] = 0.5
        u[:, case] = (x @ eps.T).reshape(-1)
    return u


def _element_dofs(solid, dofs_per_node):
    """Global DOF numbers (elements x 8D) of the solid voxels; all grid points numbered."""
    nz, ny, nx = solid.shape
    z, y, x = np.nonzero(solid)
    nodes = []
    for cx, cy, cz in ((CORNERS + 1) / 2).astype(int):
        nodes.append(((x + cx) % nx) + nx * (((y + cy) % ny) + ny * ((z + cz) % nz)))
    nodes = np.stack(nodes, axis=1)  # elements x 8
    D = dofs_per_node
    return (nodes[:, :, None] * D + np.arange(D)[None, None, :]).reshape(len(x), 8 * D)


def homogenize(solid, h, ke, fe, u0, method="auto"):
    """C^H from element matrices; solid is a bool array [z, y, x]."""
    solid = np.asarray(solid, dtype=bool)
    ncase = fe.shape[1]
    volume = solid.size * np.prod(h)
    if not solid.any():
        return np.zeros((ncase, ncase))
    edof = _element_dofs(solid, fe.shape[0] // 8)
    nel, nedof = edof.shape
    rows = np.repeat(edof, nedof, axis=1).ravel()
    cols = np.tile(edof, (1, nedof)).ravel()
    ndof = solid.size * (fe.shape[0] // 8)
    K = sp.coo_matrix((np.tile(ke.ravel(), nel), (rows, cols)), shape=(ndof, ndof)).tocsr()
    F = np.zeros((ndof, ncase))
    np.add.at(F, edof.ravel(), np.tile(fe, (nel, 1)))
    active = np.unique(edof)
    Ka = K[active][:, active]
    Fa = F[active]
    chi_a = _solve(Ka, Fa, fe.shape[0] // 8, method)
    chi = np.zeros((ndof, ncase))
    chi[active] = chi_a
    CH = np.zeros((ncase, ncase))
    for i in range(ncase):
        di = u0[None, :, i] - chi[edof, i]  # elements x 8D
        for j in range(ncase):
            dj = u0[None, :, j] - chi[edof, j]
            CH[i, j] = np.einsum("ea,ab,eb->", di, ke, dj) / volume
    return CH


def _solve(K, F, dofs_per_node, method):
    n = K.shape[0]
    if method == "dense" or (method == "auto" and n <= 2000):
        # Minimum-norm least squares: exact for a consistent singular system, whatever its null space.
        return np.linalg.lstsq(K.toarray(), F, rcond=1e-12)[0]
    if method == "cg" or (method == "auto" and n > 30000):
        # Large systems: Jacobi-preconditioned CG, which converges on a consistent singular system
        # (the iterates stay in the range of K); sparse LU fills in too much beyond ~10^5 DOFs.
        M = sp.diags(1.0 / K.diagonal())
        chi = np.zeros(F.shape)
        for i in range(F.shape[1]):
            if not F[:, i].any():
                continue
            chi[:, i], info = spla.cg(K, F[:, i], tol=1e-10, atol=0.0, M=M, maxiter=100000)
            if info != 0:
                raise RuntimeError(f"reference CG did not converge (case {i})")
        return chi
    # Fix the DOFs of the first node of every connected component (rigid translations), then a
    # shift of 1e-12 of the mean diagonal for what is left (rotations of a strut, corner hinges):
    # the load is orthogonal to those modes, so they take no energy.
    D = dofs_per_node
    node_graph = (abs(K[::D, ::D]) > 0).astype(np.int8)
    ncomp, labels = csgraph.connected_components(node_graph, directed=False)
    _, first = np.unique(labels, return_index=True)
    fixed = np.zeros(n, dtype=bool)
    for d in range(D):
        fixed[first * D + d] = True
    free = np.nonzero(~fixed)[0]
    Kf = K[free][:, free].tocsc()
    Kf = Kf + sp.identity(len(free), format="csc") * (1e-12 * Kf.diagonal().mean())
    # Symmetric mode with a minimum-degree ordering of K + K^T: the default (COLAMD, partial
    # pivoting) fills in an order of magnitude more on a 3D stiffness matrix.
    lu = spla.splu(Kf, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    chi = np.zeros(F.shape)
    chi[free] = lu.solve(np.ascontiguousarray(F[free]))
    return chi


def reference_elasticity(solid, h, E, nu, method="auto"):
    ke, fe, _ = element_elastic(np.asarray(h, float), E, nu)
    return homogenize(solid, np.asarray(h, float), ke, fe, _unit_fields(np.asarray(h, float), 3), method)


def reference_conductivity(solid, h, k, method="auto"):
    ke, fe, _ = element_thermal(np.asarray(h, float), k)
    return homogenize(solid, np.asarray(h, float), ke, fe, _unit_fields(np.asarray(h, float), 1), method)


# --- cells and the driver ------------------------------------------------------------------------

def gyroid_cell(n, density, periods=1):
    """A solid gyroid network of about the given solid fraction on n^3 voxels (bool [z, y, x])."""
    t = (np.arange(n) + 0.5) / n * 2 * np.pi * periods
    z, y, x = np.meshgrid(t, t, t, indexing="ij")
    g = np.sin(x) * np.cos(y) + np.sin(y) * np.cos(z) + np.sin(z) * np.cos(x)
    return g > np.quantile(g, 1.0 - density)


def grid_cell(n, r):
    """Dong et al.'s "grid" cell: struts of radius r along the 12 edges of the unit cell, a voxel
    solid when its centre is within r of an edge (periodic)."""
    c = (np.arange(n) + 0.5) / n
    d = np.minimum(c, 1 - c)
    z, y, x = np.meshgrid(d, d, d, indexing="ij")
    return (y * y + z * z < r * r) | (x * x + z * z < r * r) | (x * x + y * y < r * r)


def write_cell(path, solid, h, E, nu):
    solid = np.asarray(solid, dtype=bool)
    nz, ny, nx = solid.shape
    with open(path, "w") as f:
        f.write(f"{nx} {ny} {nz} {h!r} {E!r} {nu!r}\n")
        f.write("".join(np.where(solid.ravel(), "1", "0")))
        f.write("\n")


def run_driver(driver, path, thermal=False, threads=None):
    cmd = [str(driver), str(path)] + (["--thermal"] if thermal else []) + (["--threads", str(threads)] if threads else [])
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def _cases():
    rng = np.random.default_rng(15)
    cases = [("gyroid 8^3", gyroid_cell(8, 0.35)),
             ("random 8^3 (islands, corner contacts)", rng.random((8, 8, 8)) < 0.35),
             ("random 7x5x6, odd sizes", rng.random((6, 5, 7)) < 0.45)]
    cols = np.zeros((6, 6, 6), dtype=bool)
    cols[1:3, 1:3, :] = True  # columns along x: percolates along x only
    cols[4, 4, 4] = True      # and an island
    cases.append(("x columns + island 6^3", cols))
    plates = np.zeros((8, 8, 8), dtype=bool)
    plates[2:4] = True  # plates normal to z: no stiffness involving z
    cases.append(("z plates 8^3", plates))
    chain = np.zeros((8, 8, 8), dtype=bool)
    i = np.arange(8)
    chain[i, i, i] = True  # voxels touching only at corners: a ball-jointed chain along (1, 1, 1)
    chain[i, (i + 4) % 8, 0] = True  # and voxels touching along edges: a hinged staircase
    cases.append(("corner chain + edge staircase 8^3", chain))
    g = gyroid_cell(16, 0.25)
    cases.append(("gyroid 16^3 (multigrid levels)", g))
    return cases


def read_cell(path):
    """A cell file of voxlat_homogenize_cell: (solid [z, y, x], h, E, nu)."""
    text = Path(path).read_text()
    header, _, body = text.partition("\n")
    nx, ny, nz, h, E, nu = header.split()
    bits = np.frombuffer("".join(body.split()).encode(), dtype=np.uint8) == ord("1")
    return bits.reshape(int(nz), int(ny), int(nx)), float(h), float(E), float(nu)


def solve_file(path, thermal, method):
    """--cell mode: this reference on a cell file, C (or K) and the time as JSON."""
    import time
    start = time.perf_counter()
    solid, h, E, nu = read_cell(path)
    C = (reference_conductivity(solid, (h, h, h), E, method) if thermal
         else reference_elasticity(solid, (h, h, h), E, nu, method))
    print(json.dumps({"K" if thermal else "C": C.tolist(), "relative_density": float(solid.mean()),
                      "seconds": time.perf_counter() - start}))
    return 0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--driver", help="voxlat_homogenize_cell: compare it with this reference on small cells")
    ap.add_argument("--cell", help="instead: solve this cell file with the reference, print JSON")
    ap.add_argument("--thermal", action="store_true")
    ap.add_argument("--method", default="auto", choices=["auto", "dense", "sparse", "cg"])
    ap.add_argument("--tolerance", type=float, default=1e-6)
    a = ap.parse_args()
    if a.cell:
        return solve_file(a.cell, a.thermal, a.method)
    if not a.driver:
        ap.error("--driver or --cell is needed")
    failures = 0
    with tempfile.TemporaryDirectory(prefix="voxlat-homog-") as d:
        for name, solid in _cases():
            h, E, nu, k = 0.5, 200.0, 0.3, 3.0
            path = Path(d) / "cell.txt"
            for thermal in (False, True):
                write_cell(path, solid, h, k if thermal else E, nu)
                got = run_driver(a.driver, path, thermal)
                mine = np.array(got["K" if thermal else "C"])
                ref = (reference_conductivity(solid, (h, h, h), k) if thermal
                       else reference_elasticity(solid, (h, h, h), E, nu))
                scale = np.abs(ref).max()
                err = np.abs(mine - ref).max() / scale if scale > 0 else np.abs(mine).max()
                ok = err <= a.tolerance
                failures += not ok
                print(f"{'ok  ' if ok else 'FAIL'} {name:<40} {'K' if thermal else 'C'}: max rel. diff {err:.2e} "
                      f"(density {got['relative_density']:.3f}, islands {got['islands_removed']}, "
                      f"percolates {got['percolates']}, iterations {got['iterations']})")
    print("homogenization reference:", "all agree" if failures == 0 else f"{failures} differ")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
