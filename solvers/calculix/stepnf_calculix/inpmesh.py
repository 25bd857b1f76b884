"""Reading a user's mesh from an Abaqus/CalculiX ``.inp`` file (``*NODE`` and ``*ELEMENT`` blocks).

Only the mesh is taken: every ``*NODE`` line and every ``*ELEMENT`` block of
a solid element type (``C3D*``); sets, materials, sections and steps in the
file are ignored (stepnf writes its own, with the scene's material applied to
all elements). ``*INCLUDE`` is followed relative to the including file.
Continuation lines of ``*ELEMENT`` (a line ending with a comma) are joined.
Nodes that no element uses are dropped (they would carry no stiffness).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stepnf.errors import MeshError
from stepnf.geometry.checks import check_volume_mesh

#: Solid element types accepted, with their number of nodes.
SOLID_TYPES = {"C3D4": 4, "C3D6": 6, "C3D8": 8, "C3D8R": 8, "C3D8I": 8, "C3D10": 10, "C3D15": 15,
               "C3D20": 20, "C3D20R": 20}


@dataclass
class InpMesh:
    """Nodes (ids (N,), points (N, 3)) and element blocks ``[(ccx type, ids (E,), conn (E, k) node ids)]``."""

    node_ids: np.ndarray
    points: np.ndarray
    blocks: list[tuple[str, np.ndarray, np.ndarray]]


def _options(line: str) -> tuple[str, dict[str, str]]:
    parts = [p.strip() for p in line[1:].split(",")]
    opts = {}
    for p in parts[1:]:
        k, _, v = p.partition("=")
        opts[k.strip().upper()] = v.strip()
    return parts[0].upper(), opts


#: ccx solid element type -> meshio/VTK cell type of the same node order (for the mesh checks).
MESHIO_TYPES = {"C3D4": "tetra", "C3D6": "wedge", "C3D8": "hexahedron", "C3D8R": "hexahedron",
                "C3D8I": "hexahedron", "C3D10": "tetra10", "C3D15": "wedge15", "C3D20": "hexahedron20",
                "C3D20R": "hexahedron20"}


def _lines(path: Path, depth: int = 0):
    """``(file, line number, stripped line)`` of every meaningful line, following ``*INCLUDE``."""
    if depth > 10:
        raise MeshError(path, "*INCLUDE nested too deeply")
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise MeshError(path, f"cannot read: {exc}") from None
    for lineno, raw in enumerate(text.splitlines(), 1):
        s = raw.strip()
        if not s or s.startswith("**"):
            continue
        if s.startswith("*") and s[1:].upper().startswith("INCLUDE"):
            _, opts = _options(s)
            inc = opts.get("INPUT")
            if not inc:
                raise MeshError(path, f"line {lineno}: *INCLUDE without INPUT=")
            yield from _lines((path.parent / inc.strip('"')).resolve(), depth + 1)
            continue
        yield path, lineno, s


def read_inp_mesh(path: str | Path) -> InpMesh:
    """Read the solid mesh of ``path``; raise :class:`~stepnf.errors.MeshError` (a ``ValueError``)
    naming the file, the line, or the element or node (the file's ids) at fault.

    The nodes and elements found are checked by
    :func:`stepnf.geometry.checks.check_volume_mesh` (NaN coordinates, undefined
    nodes, flat meshes, coincident nodes, degenerate, tangled or overlapping elements).
    """
    path = Path(path)
    if not path.is_file():
        raise MeshError(path, f"mesh file {path} does not exist")
    nodes: dict[int, list[float]] = {}
    blocks: dict[str, list[list[int]]] = {}
    section = None
    etype = None
    pending: list[str] = []
    start = 0
    for src, lineno, s in _lines(path):
        where = f"line {lineno}" + ("" if src == path else f" of {src}")
        if s.startswith("*"):
            if pending:
                raise MeshError(path, f"{where}: the *ELEMENT line before it ends with a comma (an unfinished "
                                      "element)")
            kw, opts = _options(s)
            if kw == "NODE":
                section = "node"
            elif kw == "ELEMENT":
                etype = opts.get("TYPE", "").upper()
                if etype not in SOLID_TYPES:
                    raise MeshError(path, f"{where}: element type {etype!r} is not supported. Pick one of "
                                          f"{sorted(SOLID_TYPES)}")
                section = "element"
                blocks.setdefault(etype, [])
            else:
                section = None
            continue
        if section == "node":
            v = [t for t in s.split(",") if t.strip()]
            try:
                if len(v) < 2:
                    raise ValueError("no coordinates")
                nid = int(v[0])
                xyz = [float(x) for x in v[1:4]]
            except ValueError as exc:
                raise MeshError(path, f"{where}: expected 'node id, x, y, z', got {s[:60]!r} ({exc})") from None
            nodes[nid] = xyz + [0.0] * (3 - len(xyz))
        elif section == "element":
            if not pending:
                start = lineno
            pending.append(s)
            if s.endswith(","):
                continue
            try:
                vals = [int(t) for t in " ".join(pending).replace(",", " ").split()]
            except ValueError as exc:
                raise MeshError(path, f"line {start}: expected integer element and node ids ({exc})") from None
            pending = []
            if len(vals) != SOLID_TYPES[etype] + 1:
                raise MeshError(path, f"line {start}: a {etype} element needs {SOLID_TYPES[etype]} nodes, got "
                                      f"{len(vals) - 1}")
            blocks[etype].append(vals)
    if pending:
        raise MeshError(path, f"line {start}: the file ends inside an element (a truncated file?)")
    blocks = {t: rows for t, rows in blocks.items() if rows}
    if not blocks:
        raise MeshError(path, f"no elements: no *ELEMENT block of a solid type {sorted(SOLID_TYPES)} with "
                              "elements in it")
    if not nodes:
        raise MeshError(path, "no nodes: no *NODE block with nodes in it")
    out_blocks = []
    used: set[int] = set()
    for t, rows in blocks.items():
        a = np.array(rows, dtype=np.int64)
        out_blocks.append((t, a[:, 0], a[:, 1:]))
        used.update(a[:, 1:].ravel().tolist())
    missing = sorted(used - set(nodes))
    if missing:
        for t, eids, conn in out_blocks:
            bad = ~np.isin(conn, np.array(sorted(nodes), dtype=np.int64))
            if bad.any():
                e = int(np.nonzero(bad.any(axis=1))[0][0])
                raise MeshError(path, f"{t} element {int(eids[e])} uses node {int(conn[e][bad[e]][0])}, which no "
                                      f"*NODE line defines; {len(missing)} undefined node(s), e.g. {missing[:5]}")
    ids = np.array(sorted(used), dtype=np.int64)
    pts = np.array([nodes[i] for i in ids], dtype=float)
    check_volume_mesh(pts, [(MESHIO_TYPES[t], np.searchsorted(ids, c))
                            for t, _, c in out_blocks],
                      source=path, node_ids=ids, cell_ids=[e for _, e, _ in out_blocks],
                      cell_labels=[f"{t} element" for t, _, _ in out_blocks])
    return InpMesh(ids, pts, out_blocks)
