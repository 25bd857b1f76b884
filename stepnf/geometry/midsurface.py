"""Mid-surface sampling of 20-node brick meshes, for the transverse amplitude of a mode (Gamma).

A 20-node mesh has fewer mid-surface nodes than the 27-node mesh of the same
geometry (no face-centre nodes), so the largest nodal transverse displacement
would be sampled more coarsely. :func:`midsurface_sampler` returns the
interpolation matrix from node displacements to the values at the 3 x 3 grid
of reference points of every element's mid-surface level (the positions of
a 27-node element's mid-surface nodes), so both discretisations take the
maximum over the same points. Node order: VTK's ``hexahedron20``.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

#: Element nodes lying on each reference level zeta = 0, 1/2, 1 (corners or vertical-edge mid-nodes).
_LEVEL_NODES = {0.0: [0, 1, 2, 3], 0.5: [16, 17, 18, 19], 1.0: [4, 5, 6, 7]}


def midsurface_sampler(points: np.ndarray, cells: np.ndarray, midsurface: np.ndarray
                       ) -> tuple[sp.csr_matrix, np.ndarray]:
    """Interpolation matrix ``W`` (S, N) and sample positions (S, 3) on the mid-surface.

    ``cells`` (E, 20) in VTK order, 0-based; ``midsurface`` (N,) bool. An
    element contributes the 9 points of each reference level whose four
    defining nodes are all mid-surface nodes.
    """
    from stepnf.geometry import shape_functions

    cells = np.asarray(cells, dtype=np.int64)
    mid = np.asarray(midsurface, dtype=bool)
    rows, cols, vals, pos = [], [], [], []
    g = np.array([0.0, 0.5, 1.0])
    s = 0
    for zeta, nodes in _LEVEL_NODES.items():
        sel = np.nonzero(mid[cells[:, nodes]].all(axis=1))[0]
        if not sel.size:
            continue
        xi = np.array([[x, y, zeta] for x in g for y in g])
        N, _ = shape_functions(xi, 20)  # (9, 20)
        for e in sel:
            c = cells[e]
            rows.append(np.repeat(np.arange(s, s + 9), 20))
            cols.append(np.tile(c, 9))
            vals.append(N.ravel())
            pos.append(N @ points[c])
            s += 9
    if s == 0:
        return sp.csr_matrix((0, len(points))), np.zeros((0, 3))
    W = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(s, len(points)))
    return W, np.concatenate(pos)
