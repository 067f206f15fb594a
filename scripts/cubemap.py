"""Cubemap conventions of docs/CUBEMAP.md in NumPy (used by sample generators and tests).

Face order +X, -X, +Y, -Y, +Z, -Z; column index face*R*R + t*R + s; texel centre
(u, v) = (2(s+0.5)/R - 1, 2(t+0.5)/R - 1); exact texel solid angles.
"""
import numpy as np


def face_direction(face, u, v):
    """Unnormalised direction through face coordinates (u, v) in [-1, 1]."""
    one = np.ones_like(u)
    return {
        0: (one, -v, -u),    # +X
        1: (-one, -v, u),    # -X
        2: (u, one, v),      # +Y
        3: (u, -one, -v),    # -Y
        4: (u, -v, one),     # +Z
        5: (-u, -v, -one),   # -Z
    }[face]


def texel_directions(R):
    """(6R^2, 3) unit directions through texel centres, in column order."""
    s = (np.arange(R) + 0.5) * 2.0 / R - 1.0
    u, v = np.meshgrid(s, s)  # u varies with s (columns), v with t (rows)
    dirs = []
    for f in range(6):
        x, y, z = face_direction(f, u, v)
        d = np.stack([x, y, z], axis=-1).reshape(-1, 3)
        dirs.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    return np.concatenate(dirs)


def texel_solid_angles(R):
    """(6R^2,) exact solid angle of each texel; they sum to 4*pi."""
    def area(x, y):
        return np.arctan2(x * y, np.sqrt(x * x + y * y + 1.0))

    e = np.arange(R + 1) * 2.0 / R - 1.0
    x0, y0 = np.meshgrid(e[:-1], e[:-1])
    x1, y1 = np.meshgrid(e[1:], e[1:])
    face = (area(x1, y1) - area(x0, y1) - area(x1, y0) + area(x0, y0)).reshape(-1)
    return np.tile(face, 6)
