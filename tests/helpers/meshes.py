"""Structured test meshes shared by the CalculiX and hostile-input tests, and the FE cap's scene tables."""
from __future__ import annotations

import numpy as np


def block_mesh(nx: int, ny: int, nz: int, size=(1.0, 1.0, 0.1), A: np.ndarray | None = None):
    """Structured block of hex20 (VTK order), optionally mapped by the affine matrix ``A``.

    Returns points (N, 3) and cells (E, 20), 0-based; face and body centres are left out.
    """
    corners = [(0, 0, 0), (2, 0, 0), (2, 2, 0), (0, 2, 0), (0, 0, 2), (2, 0, 2), (2, 2, 2), (0, 2, 2)]
    edges = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
    local = np.array(corners + [tuple((np.add(corners[i], corners[j])) // 2) for i, j in edges])
    index: dict[tuple, int] = {}
    cells = []
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                cells.append([index.setdefault(tuple(np.array([2 * i, 2 * j, 2 * k]) + d), len(index)) for d in local])
    grid = np.array(sorted(index, key=index.get), dtype=float)
    pts = grid / np.array([2 * nx, 2 * ny, 2 * nz]) * np.array(size)
    if A is not None:
        pts = pts @ np.asarray(A).T
    return pts, np.array(cells)


def hex20_block(nx=2, ny=2, nz=1, size=(0.3, 0.3, 0.02)):
    """Structured 20-node bricks (VTK order == CalculiX C3D20 order)."""
    return block_mesh(nx, ny, nz, size=size)


def cap_model_toml(n_core: int, n_ring: int) -> str:
    """The ``[model]`` tables of a FEniCSx scene of the paper's kappa = 25 cap (hex27; a = 0.15 m, R = 1.5 m,
    h = 0.003 m; E = 1.04e11 Pa, nu = 0.3, rho = 4400 kg/m^3) on the O-grid ``n_core`` x ``n_ring``: the
    FE tests' scenes append their ``[analysis]`` and ``[output]`` tables."""
    return ('[model]\nsolver = "fenicsx"\nelement = "hex27"\n[model.geometry]\nshape = "spherical_cap"\n'
            f'a = 0.15\nR = 1.5\nh = 0.003\nn_core = {n_core}\nn_ring = {n_ring}\n'
            '[model.material]\nE = 1.04e11\nnu = 0.3\nrho = 4400.0\n')
