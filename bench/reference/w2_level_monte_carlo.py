#!/usr/bin/env python3
"""W2 check: the iso-value for 20 % of the box, from independent uniform random points.

The W2 reference (w2_numpy_convolution.py) takes the quantile of F over voxel centres. Its 5 mm
cells are exactly 50 voxels, so every cell is sampled at the same points and the count aliases:
its level moves by 1.5 % with the sample grid's offset. Points drawn independently and uniformly
in the box have no lattice to alias with: the fraction of them with F >= t estimates the volume
fraction of the seed's definition (rho = vol{F >= t} / V) without bias, with a binomial standard
error, and the level follows by interpolating that fraction in t.

F is the reference's own: the closed-form Gaussian line integral of each BCC strut, cut to the
strut's box grown by r_c = sigma sqrt(2 ln 1e4), summed. A strut lies inside its cell and reaches
r_c < one cell beyond it, so only the struts of the 27 cells around a point's cell are summed.

Usage: w2_level_monte_carlo.py [--samples N] [--seed S] [--at T ...]
"""
import argparse
import itertools

import numpy as np
from scipy.special import erf

# W2: the acceptance recipe's lattice, as in the reference's defaults.
SIZE, CELL, SIGMA, DENSITY = 50.0, 5.0, 0.5, 0.20


def strut_field(p, a, b, sigma, rc):
    """The reference's F_j at points p (n x 3) for the strut a-b, zero outside its sub-domain box."""
    length = np.linalg.norm(b - a)
    u = (b - a) / length
    inside = np.all((p >= np.minimum(a, b) - rc) & (p <= np.maximum(a, b) + rc), axis=1)
    x = p - a
    h = x @ u
    r2 = np.einsum("ij,ij->i", x, x) - h * h
    f = np.exp(-r2 / (2 * sigma * sigma)) * (sigma * np.sqrt(np.pi / 2)) * (
        erf((length - h) / (sigma * np.sqrt(2))) + erf(h / (sigma * np.sqrt(2))))
    return np.where(inside, f, 0.0)


def field(p, size, cell, sigma, rc):
    n = int(round(size / cell))
    home = np.minimum(np.floor(p / cell).astype(int), n - 1)
    total = np.zeros(len(p))
    for d in itertools.product((-1, 0, 1), repeat=3):
        c = home + np.array(d)
        ok = np.all((c >= 0) & (c < n), axis=1)
        # Each point relative to the centre of its neighbour cell c: every cell's strut to a
        # given corner is then the same segment, for all the points at once.
        shifted = p - (c + 0.5) * cell
        for corner in itertools.product((0, 1), repeat=3):
            f = strut_field(shifted, np.zeros(3), (np.array(corner) - 0.5) * cell, sigma, rc)
            total += np.where(ok, f, 0.0)
    return total


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=12_000_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--at", type=float, nargs="*", default=[], help="also print the fraction with F >= each level")
    a = ap.parse_args()
    rc = SIGMA * np.sqrt(2 * np.log(1e4))
    rng = np.random.default_rng(a.seed)
    chunk = 1_000_000
    values = []
    for start in range(0, a.samples, chunk):
        p = rng.random((min(chunk, a.samples - start), 3)) * SIZE
        values.append(field(p, SIZE, CELL, SIGMA, rc).astype(np.float32))
    f = np.concatenate(values)
    level = float(np.quantile(f, 1.0 - DENSITY))
    # The level's standard error: the fraction's binomial error over the slope of the fraction in t.
    se_fraction = np.sqrt(DENSITY * (1 - DENSITY) / len(f))
    dt = 0.002 * level
    slope = (np.mean(f >= level - dt) - np.mean(f >= level + dt)) / (2 * dt)
    print(f"samples {len(f)}, seed {a.seed}: level {level:.6f} +- {se_fraction / slope:.6f} (one standard error)")
    for t in a.at:
        frac = float(np.mean(f >= t))
        print(f"fraction with F >= {t}: {frac:.5f} +- {np.sqrt(frac * (1 - frac) / len(f)):.5f}")


if __name__ == "__main__":
    main()
