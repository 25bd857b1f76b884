"""Conforming split of 27-node hexahedral meshes into straight tetrahedra (pure numpy).

Each hexahedron is cut into 24 tetrahedra (corner, next corner, face centre,
body centre) using only its own nodes, so neighbouring cells always agree on
the shared faces whatever their orientation. The vertices lie on the curved
geometry; edges and faces are straight (use a P2 field on it for "tet10").
"""
from __future__ import annotations

import numpy as np

from stepnf.geometry.cap import VolumeMesh

#: corners of the VTK hexahedron's faces (-x +x -y +y -z +z), cyclic, and their centre nodes
_FACES = [((0, 3, 7, 4), 20), ((1, 2, 6, 5), 21), ((0, 1, 5, 4), 22), ((3, 2, 6, 7), 23),
          ((0, 1, 2, 3), 24), ((4, 5, 6, 7), 25)]


def hex27_to_tetra(mesh: VolumeMesh) -> VolumeMesh:
    """Linear tetrahedra (``"tetra"``) with positive volume filling a ``hexahedron27`` mesh."""
    if mesh.cell_type != "hexahedron27":
        raise ValueError(f"hex27_to_tetra needs a 'hexahedron27' mesh, got {mesh.cell_type!r}")
    local = []
    for corners, centre in _FACES:
        for i in range(4):
            local.append((corners[i], corners[(i + 1) % 4], centre, 26))
    tets = mesh.cells[:, np.array(local)].reshape(-1, 4)
    P = mesh.points
    d = np.einsum("ij,ij->i", np.cross(P[tets[:, 1]] - P[tets[:, 0]], P[tets[:, 2]] - P[tets[:, 0]]),
                  P[tets[:, 3]] - P[tets[:, 0]])
    tets[d < 0] = tets[d < 0][:, [1, 0, 2, 3]]
    used = np.unique(tets)
    renum = np.full(len(P), -1)
    renum[used] = np.arange(len(used))
    mid = None if mesh.midsurface is None else mesh.midsurface[used]
    info = dict(mesh.info, element="tet10")
    # named node sets keep the nodes the tetrahedra still use (the hexahedra's mid-edge nodes are dropped)
    sets = {k: np.unique(renum[v][renum[v] >= 0]) for k, v in mesh.node_sets.items()}
    return VolumeMesh(points=P[used], cells=renum[tets], cell_type="tetra", midsurface=mid, info=info,
                      node_sets=sets)
