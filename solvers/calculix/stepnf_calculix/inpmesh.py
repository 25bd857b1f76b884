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


def _lines(path: Path, depth: int = 0):
    if depth > 10:
        raise ValueError(f"{path}: *INCLUDE nested too deeply")
    for raw in path.read_text(errors="replace").splitlines():
        s = raw.strip()
        if not s or s.startswith("**"):
            continue
        if s.startswith("*") and s[1:].upper().startswith("INCLUDE"):
            _, opts = _options(s)
            inc = opts.get("INPUT")
            if not inc:
                raise ValueError(f"{path}: *INCLUDE without INPUT=")
            yield from _lines((path.parent / inc.strip('"')).resolve(), depth + 1)
            continue
        yield s


def read_inp_mesh(path: str | Path) -> InpMesh:
    """Read the solid mesh of ``path``; raise ``ValueError`` naming the file and the problem."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"mesh file {path} does not exist")
    nodes: dict[int, list[float]] = {}
    blocks: dict[str, list[list[int]]] = {}
    section = None
    etype = None
    pending: list[str] = []
    for s in _lines(path):
        if s.startswith("*"):
            kw, opts = _options(s)
            if kw == "NODE":
                section = "node"
            elif kw == "ELEMENT":
                etype = opts.get("TYPE", "").upper()
                if etype not in SOLID_TYPES:
                    raise ValueError(
                        f"{path}: element type {etype!r} is not supported. Pick one of {sorted(SOLID_TYPES)}"
                    )
                section = "element"
                blocks.setdefault(etype, [])
            else:
                section = None
            continue
        if section == "node":
            v = [t for t in s.split(",") if t.strip()]
            nodes[int(v[0])] = [float(x) for x in v[1:4]] + [0.0] * (3 - len(v[1:4]))
        elif section == "element":
            pending.append(s)
            if s.endswith(","):
                continue
            vals = [int(t) for t in " ".join(pending).replace(",", " ").split()]
            pending = []
            if len(vals) != SOLID_TYPES[etype] + 1:
                raise ValueError(f"{path}: a {etype} element needs {SOLID_TYPES[etype]} nodes, got {len(vals) - 1}")
            blocks[etype].append(vals)
    if not blocks:
        raise ValueError(f"{path}: no *ELEMENT block of a solid type {sorted(SOLID_TYPES)}")
    out_blocks = []
    used: set[int] = set()
    for t, rows in blocks.items():
        a = np.array(rows, dtype=np.int64)
        out_blocks.append((t, a[:, 0], a[:, 1:]))
        used.update(a[:, 1:].ravel().tolist())
    missing = sorted(used - set(nodes))
    if missing:
        raise ValueError(f"{path}: elements use undefined nodes, e.g. {missing[:5]}")
    ids = np.array(sorted(used), dtype=np.int64)
    pts = np.array([nodes[i] for i in ids], dtype=float)
    return InpMesh(ids, pts, out_blocks)
