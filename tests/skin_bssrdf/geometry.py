"""Test geometry for the diffusion operators: planar texel grids."""

import numpy as np


def plane(n, h, *, m=None):
    """n x m samples on z = 0 with spacing h (mm), row-major; positions [P, 3], areas [P], texel [P, 2]."""
    m = n if m is None else m
    r, c = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    pos = np.stack([c.ravel() * h, r.ravel() * h, np.zeros(n * m)], -1)
    return pos, np.full(n * m, h * h), np.stack([r.ravel(), c.ravel()], -1)
