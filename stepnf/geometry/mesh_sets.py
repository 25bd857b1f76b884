"""Named sets of a mesh read by meshio: node sets and volume-cell sets from point sets, cell sets, Gmsh
physical groups (of any dimension: a group of facets names their nodes) and MED groups.

Shared by the solver routes that read a user's mesh through meshio (``.msh``, ``.med``, ``.vtu``...): the
``fenicsx`` adapter's mesh files and the ``calculix`` adapter's Gmsh ``.msh``. No meshio import here: the
functions take the ``meshio.Mesh`` read by the caller.
"""
from __future__ import annotations

from typing import Any, Iterator, Mapping

import numpy as np

#: topological dimension of meshio cell types (by name prefix)
_DIMS = (("vertex", 0), ("line", 1), ("triangle", 2), ("quad", 2), ("polygon", 2), ("tetra", 3),
         ("hexahedron", 3), ("wedge", 3), ("pyramid", 3))


def cell_dimension(cell_type: str) -> int | None:
    """Topological dimension of a meshio cell type (``None`` when unknown)."""
    return next((d for p, d in _DIMS if cell_type.startswith(p)), None)


def named_cells(m: Any) -> Iterator[tuple[str, int, np.ndarray]]:
    """``(name, block, positions)`` of every named group of cells of a meshio mesh: meshio cell sets (an
    Abaqus ``*ELSET``...), Gmsh physical groups (``gmsh:physical`` cell data named by ``field_data``: the
    cells of that tag in the blocks of the group's dimension), MED groups of cells (families of
    ``cell_tags``); ``positions`` are the cells' rows within block ``block`` of ``m.cells``."""
    cell_data: Mapping[str, Any] = getattr(m, "cell_data", None) or {}
    for name, per_block in (getattr(m, "cell_sets", None) or {}).items():
        if not str(name).startswith("gmsh:"):
            for b, idx in enumerate(per_block):
                if idx is not None and len(idx) and b < len(m.cells):
                    yield str(name), b, np.asarray(idx, dtype=np.int64).ravel()
    groups: list[tuple[str, Any, Any, int | None]] = []  # (name, cell data, tag, dimension)
    if "gmsh:physical" in cell_data:
        for name, value in (getattr(m, "field_data", None) or {}).items():
            value = np.asarray(value).ravel()
            groups.append((name, cell_data["gmsh:physical"], int(value[0]), int(value[1]) if len(value) > 1 else None))
    for tag, names in (getattr(m, "cell_tags", None) or {}).items() if "cell_tags" in cell_data else ():
        groups += [(name, cell_data["cell_tags"], tag, None) for name in names]
    for name, tags, tag, dim in groups:
        for b, t in enumerate(tags):
            if b < len(m.cells) and (dim is None or cell_dimension(m.cells[b].type) == dim):
                yield str(name), b, np.flatnonzero(np.asarray(t) == tag)


def read_node_sets(m: Any, renum: np.ndarray) -> dict[str, np.ndarray]:
    """Named node sets ``{name: sorted node indices}`` of a meshio mesh, numbered by ``renum`` (file
    node -> mesh node, -1 for nodes no volume cell uses, which are dropped).

    Point sets; the nodes of every named group of cells (:func:`named_cells`, whatever their dimension:
    a Gmsh physical group of facets names the nodes of those facets); MED groups of nodes (families of
    ``point_tags``). A name found in several of these gets the union.
    """
    found: dict[str, list[np.ndarray]] = {}

    def add(name: str, nodes: Any) -> None:
        found.setdefault(str(name), []).append(np.asarray(nodes, dtype=np.int64).ravel())

    for name, idx in (getattr(m, "point_sets", None) or {}).items():
        add(name, idx)
    for name, b, idx in named_cells(m):
        add(name, np.asarray(m.cells[b].data)[idx])
    point_tags = (getattr(m, "point_data", None) or {}).get("point_tags")
    for tag, names in (getattr(m, "point_tags", None) or {}).items() if point_tags is not None else ():
        for name in names:
            add(name, np.flatnonzero(np.asarray(point_tags) == tag))
    out = {}
    for name, parts in found.items():
        nodes = np.unique(np.concatenate(parts))
        nodes = renum[nodes[(nodes >= 0) & (nodes < len(renum))]]
        out[name] = np.unique(nodes[nodes >= 0])
    return out


def read_cell_sets(m: Any, kind: str) -> dict[str, np.ndarray]:
    """Named sets of volume cells ``{name: sorted cell indices}`` of a meshio mesh (:func:`named_cells`
    holding cells of type ``kind``), numbered like :func:`read_mesh`'s cells: the cells of type ``kind``
    in file order. A name holding only facets (or other cells) is no cell set."""
    offset, n = {}, 0
    for b, block in enumerate(m.cells):
        if block.type == kind:
            offset[b], n = n, n + len(block.data)
    found: dict[str, list[np.ndarray]] = {}
    for name, b, idx in named_cells(m):
        if b in offset and len(idx):
            found.setdefault(name, []).append(offset[b] + idx)
    return {name: np.unique(np.concatenate(parts)) for name, parts in found.items()}
