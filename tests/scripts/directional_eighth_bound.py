#!/usr/bin/env python3
"""The table of fields/struts/ColumnStencils.cpp: a ray's eighth derivative along x, per unit of its peak.

A ray of the Gaussian kernel (sigma 1, unit weight, from the origin along u) has
F(q) = sqrt(2 pi) Phi(h) exp(-r^2 / 2), h = q.u. With x = b u + a n (b = |u.x|, a = sqrt(1 - b^2),
n the unit normal in the plane of u and x), D_x^8 = sum_k C(8, k) a^(8-k) b^k D_n^(8-k) D_u^k, and
  D_n^j exp(-t_n^2 / 2) = (-1)^j He_j(t_n) exp(-t_n^2 / 2),
  D_u^k sqrt(2 pi) Phi(h) = (-1)^(k-1) He_(k-1)(h) exp(-h^2 / 2)   (k >= 1),
so f8 = D_x^8 F / sqrt(2 pi) is a sum of nine terms in (t_n, h); the third coordinate t_m only
scales it by exp(-t_m^2 / 2). R(b) = sup |f8| exp(d^2 / 4), d the distance to the ray
(d^2 = t_n^2 + t_m^2 + min(h, 0)^2; t_m = 0 is the worst, as exp(-t_m^2 / 2 + t_m^2 / 4) <= 1).

Prints, for b in [i / 64, (i + 1) / 64], the largest R over five b in the interval on a
0.01 grid of (t_n, h) in [-10, 10] x [-12, 12], times 1.01 (the grid's and the b samples' slack;
the test recomputes R at b between the samples). Takes about two minutes.
"""
from math import comb, sqrt, pi

import numpy as np
from numpy.polynomial.hermite_e import hermeval
from scipy.special import ndtr

TN, H = np.meshgrid(np.linspace(-10, 10, 2001), np.linspace(-12, 12, 2401), indexing="ij")
ENVELOPE = np.exp((TN**2 + np.minimum(H, 0.0) ** 2) / 4.0)


def hermite(j, x):
    c = np.zeros(j + 1)
    c[j] = 1.0
    return hermeval(x, c)


NORMAL = [(-1) ** (8 - k) * hermite(8 - k, TN) * np.exp(-TN**2 / 2) for k in range(9)]
ALONG = [ndtr(H)] + [(-1) ** (k - 1) * hermite(k - 1, H) * np.exp(-H**2 / 2) / sqrt(2 * pi) for k in range(1, 9)]


def ray_bound(b):
    a = sqrt(max(0.0, 1.0 - b * b))
    f8 = sum(comb(8, k) * a ** (8 - k) * b**k * NORMAL[k] * ALONG[k] for k in range(9))
    return float(np.max(np.abs(f8) * ENVELOPE))


samples = {}
rows = []
for i in range(64):
    worst = 0.0
    for s in range(5):
        b = (4 * i + s) / 256.0
        if b not in samples:
            samples[b] = ray_bound(b)
        worst = max(worst, samples[b])
    rows.append(1.01 * worst)
print(",\n".join(", ".join(f"{v:.2f}" for v in rows[r : r + 8]) for r in range(0, 64, 8)))
