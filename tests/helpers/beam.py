"""A slender clamped-clamped beam of hexahedra for the FEniCSx adapters' tests (boundary conditions, materials).

[0, L] x [-B/2, B/2] x [-HB/2, HB/2] in metres: L / HB = 100, width B = 2 HB, so the first mode bends in z.
"""
from __future__ import annotations

import json

import numpy as np

from stepnf.geometry.hexahedra import HEX27_NODES

L, B, HB = 1.0, 0.02, 0.01
NX = 40  # 40 x 1 x 1 quadratic hexahedra, 2 133 free dofs

#: VTK hexahedron27 nodes in half-cell steps: corners, edge mid-nodes, face centres, body centre
_HEX27 = (2 * HEX27_NODES).astype(int)


def beam_mesh(n=(NX, 1, 1), linear: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Points and VTK cells (hexahedron27, or hexahedron when ``linear``) of [0, L] x [-B/2, B/2] x [-HB/2, HB/2]."""
    local = _HEX27[:8] if linear else _HEX27
    index: dict[tuple, int] = {}
    cells = [[index.setdefault(tuple(np.array([2 * i, 2 * j, 2 * k]) + d), len(index)) for d in local]
             for i in range(n[0]) for j in range(n[1]) for k in range(n[2])]
    grid = np.array(sorted(index, key=index.get), dtype=float)
    return grid / (2 * np.array(n)) * [L, B, HB] - [0, B / 2, HB / 2], np.array(cells)


def boundary_toml(bcs) -> str:
    """``[[model.boundary]]`` tables of a scene, one per condition (a dict of its keys)."""
    rows = []
    for bc in bcs:
        rows.append("[[model.boundary]]")
        rows += [f"{k} = {json.dumps(v)}" for k, v in bc.items()]
    return "\n".join(rows)


def beam_scene(mesh: str, bcs, *, methods=("dnf", "md", "smd"), analysis: str = "", out: str = "out") -> str:
    """A FEniCSx scene of the beam's mesh file ``mesh`` (steel, nu = 0.3), the conditions ``bcs``
    (:func:`boundary_toml`), master mode 0, thickness HB, transverse uz; ``analysis``: more lines (tables)
    after ``[analysis]``; no plot."""
    return (f'[model]\nsolver = "fenicsx"\nmesh = "{mesh}"\n[model.material]\nE = 2.1e11\nnu = 0.3\n'
            f'rho = 7800.0\n{boundary_toml(bcs)}\n[analysis]\nmaster_modes = [0]\n'
            f'methods = {json.dumps(list(methods))}\nthickness = {HB!r}\ntransverse = "uz"\n{analysis}\n'
            f'[output]\ndir = "{out}"\nplot = false\n')
