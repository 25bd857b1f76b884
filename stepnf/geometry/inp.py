"""Reading Abaqus/CalculiX ``.inp`` text: lines through ``*INCLUDE``, keyword blocks, nodes, elements, sets.

The one ``.inp`` reader of stepnf: both solver routes read a user's ``.inp`` mesh
with :func:`read_inp_mesh` (the ``mesh`` key of the ``calculix`` and ``fenicsx``
adapters), and the ``calculix`` adapter reads a whole deck (``deck =
"model.inp"``, ``stepnf_calculix.userdeck``) on the same blocks.

* :func:`inp_lines` yields every meaningful line (comments ``**`` and blank
  lines skipped) with its file and line number, following ``*INCLUDE,
  INPUT=...`` where it stands. A relative ``INPUT`` is relative to the folder
  of the top file (ccx runs in the deck's folder and opens every include from
  there, nested ones too); a missing file and an include cycle are errors
  naming the ``*INCLUDE`` line.
* :func:`keyword_blocks` groups them into :class:`Block` s: a keyword line
  (name upper-cased, blanks collapsed: ``*Solid  section`` is ``SOLID
  SECTION``; options ``{NAME: value}`` with upper-case names) and its data lines.
* :class:`InpModel` collects ``*NODE``, ``*ELEMENT`` (3D solid types; with
  ``facets=True`` also the surface and line elements of :data:`FACET_TYPES`,
  which a mesher such as Gmsh writes beside the volumes), ``*NSET`` and
  ``*ELSET`` (ids, names of sets defined before, ``GENERATE`` ranges) and
  gives the mesh (:meth:`InpModel.mesh`): the nodes some solid element uses,
  sorted by id, and the named node sets (``*NSET`` s, and the nodes of
  ``*ELSET`` s without an ``*NSET`` of the same name, facets included; names
  are upper-case and looked up case-insensitively, as ccx does). Facet
  elements are no part of the model: only their nodes name sets (for
  boundary conditions); :attr:`InpMesh.facets` counts them by type.

Every error is a :class:`~stepnf.errors.MeshError` (a SceneError, exit code 2)
naming the top file and the line (``line 3 of sub.inp, included at line 5``).
"""
from __future__ import annotations

import ast
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator, NamedTuple

import numpy as np

from stepnf.errors import MeshError
from stepnf.geometry.checks import check_volume_mesh

#: Solid element types accepted, with their number of nodes.
SOLID_TYPES = {"C3D4": 4, "C3D6": 6, "C3D8": 8, "C3D8R": 8, "C3D10": 10, "C3D15": 15, "C3D20": 20, "C3D20R": 20}
#: ccx solid element type -> meshio/VTK cell type of the same node order (for the mesh checks).
MESHIO_TYPES = {"C3D4": "tetra", "C3D6": "wedge", "C3D8": "hexahedron", "C3D8R": "hexahedron",
                "C3D10": "tetra10", "C3D15": "wedge15", "C3D20": "hexahedron20", "C3D20R": "hexahedron20"}
#: Surface and line element types taken as facets of a solid mesh (``facets=True``), with their number of
#: nodes: Gmsh's ``.inp`` export writes its surface and line elements as CPS*/T3D*; shells, membranes,
#: plane and axisymmetric elements and beams of a mixed deck are read the same way (sets, not model).
FACET_TYPES = {**{f"{p}{n}{r}": n for p in ("S", "CPS", "CPE", "CAX", "M3D") for n in (3, 4, 6, 8)
                  for r in ("", "R")},
               "S9R5": 9, "STRI3": 3, "STRI65": 6, "S4R5": 4, "CPS9": 9, "CPE9": 9, "M3D9": 9, "M3D9R": 9,
               "B31": 2, "B31R": 2, "B32": 3, "B32R": 3, "T3D2": 2, "T3D3": 3, "T2D2": 2, "T2D3": 3}
#: Abaqus variants of the solid types (hybrid ``H``, modified ``M``: another formulation of the same element
#: geometry; meshio writes its hexahedra as C3D8RH and C3D20RH): read as the base type by the mesh route
#: (``facets=True``: the file gives the geometry, stepnf the formulation), refused in a deck.
VARIANTS = {"C3D4H": "C3D4", "C3D6H": "C3D6", "C3D8H": "C3D8", "C3D8RH": "C3D8R", "C3D10H": "C3D10", "C3D10M": "C3D10",
            "C3D10MH": "C3D10", "C3D15H": "C3D15", "C3D20H": "C3D20", "C3D20RH": "C3D20R"}
#: Solid types refused, and why.
REFUSED_TYPES = {"C3D8I": "ccx adds internal incompatible-mode dofs to each C3D8I element, which stepnf can "
                          "neither prescribe nor expose (use C3D8 or C3D20)"}


@dataclass(frozen=True)
class Source:
    """A file read, and the ``*INCLUDE`` line that brought it in (``None`` for the top file)."""

    path: Path
    via: tuple["Source", int] | None = None


class Line(NamedTuple):
    source: Source
    lineno: int
    text: str


def where(line: Line) -> str:
    """``line 12`` of the top file, or ``line 3 of sub.inp (included at line 5)`` (and ``of mid.inp`` for
    deeper includes: ``line 3 of c.inp (included at line 2 of b.inp, included at line 5)``)."""
    src = line.source
    if src.via is None:
        return f"line {line.lineno}"
    chain = []
    while src.via is not None:
        parent, at = src.via
        chain.append(f"included at line {at}" + (f" of {parent.path}" if parent.via is not None else ""))
        src = parent
    return f"line {line.lineno} of {line.source.path} ({', '.join(chain)})"


class InpError(MeshError):
    """An ``.inp`` file stepnf cannot take: the top file, the line and what is wrong (exit code 2).

    On a line of an included file the message names the file, the line and the problem but does not
    quote the line (:func:`unquoted`): ``*INCLUDE, INPUT=`` may name any file (``/etc/shadow``), and an
    error must not show its content."""

    def __init__(self, top: Path, line: Line | None, message: str, *, include_line: bool = False):
        if line is not None and line.source.via is not None and not include_line:  # an *INCLUDE names a file
            message = unquoted(message, line.text)
        super().__init__(top, f"{where(line)}: {message}" if line is not None else message)


_QUOTED = re.compile(r"'(?:[^'\\]|\\.)*'|\"(?:[^\"\\]|\\.)*\"")
HIDDEN = "<not shown: a line of an included file>"


def unquoted(message: str, text: str) -> str:
    """``message`` with every piece of ``text`` it quotes (its repr, or a field of it) replaced by :data:`HIDDEN`."""

    def hide(m: re.Match) -> str:
        try:
            inner = str(ast.literal_eval(m.group()))
        except (ValueError, SyntaxError):
            inner = m.group()[1:-1]
        return HIDDEN if inner and " ".join(inner.upper().split()) in folded else m.group()

    folded = " ".join(text.upper().split())  # keyword names are shown upper-cased, blanks collapsed
    out = _QUOTED.sub(hide, message)
    pieces = {text, *(t.strip() for t in text.replace("=", ",").split(","))}
    for piece in sorted((p for p in pieces if len(p) >= 3), key=len, reverse=True):
        # what is left unquoted (a keyword's name, an option's value), in any case and spacing
        pattern = r"\s+".join(re.escape(w) for w in piece.split())
        out = re.sub(pattern, HIDDEN, out, flags=re.IGNORECASE)
    return out


def parse_keyword(text: str) -> tuple[str, dict[str, str]]:
    """``("SOLID SECTION", {"ELSET": "E1", "MATERIAL": "STEEL"})`` of a keyword line."""
    parts = [p.strip() for p in text[1:].split(",")]
    opts = {}
    for p in parts[1:]:
        if p:
            k, _, v = p.partition("=")
            opts[" ".join(k.upper().split())] = v.strip()
    return " ".join(parts[0].upper().split()), opts


def inp_lines(top: Path) -> Iterator[Line]:
    """Every meaningful line of ``top`` and of the files it includes, in reading order."""
    top = Path(top)

    def walk(src: Source, stack: tuple[Path, ...]) -> Iterator[Line]:
        try:
            text = src.path.read_text(errors="replace")
        except OSError as exc:
            raise InpError(top, None, f"cannot read {src.path}: {exc}") from None
        for lineno, raw in enumerate(text.splitlines(), 1):
            s = raw.strip()
            if not s or s.startswith("**"):
                continue
            line = Line(src, lineno, s)
            if s.startswith("*") and parse_keyword(s)[0] == "INCLUDE":
                inc = parse_keyword(s)[1].get("INPUT", "").strip('"')
                if not inc:
                    raise InpError(top, line, "*INCLUDE without INPUT=<file>", include_line=True)
                path = Path(inc) if Path(inc).is_absolute() else top.parent / inc
                if not path.is_file():
                    raise InpError(top, line, f"*INCLUDE, INPUT={inc}: no file {path} (a relative INPUT is "
                                              f"relative to the folder of {top.name}, where ccx runs)",
                                   include_line=True)
                if path.resolve() in stack:
                    raise InpError(top, line, f"*INCLUDE, INPUT={inc}: an include cycle ({path.name} includes "
                                              "itself, directly or through other files)", include_line=True)
                yield from walk(Source(path, (src, lineno)), stack + (path.resolve(),))
                continue
            yield line

    yield from walk(Source(top), (top.resolve(),))


@dataclass
class Block:
    """A keyword line and its data lines."""

    name: str
    options: dict[str, str]
    head: Line
    data: list[Line] = field(default_factory=list)


def keyword_blocks(lines: Iterable[Line]) -> Iterator[Block]:
    """The keyword blocks of ``lines``; data before the first keyword is ignored (as ccx does)."""
    block: Block | None = None
    for line in lines:
        if line.text.startswith("*"):
            if block is not None:
                yield block
            name, opts = parse_keyword(line.text)
            block = Block(name, opts, line)
        elif block is not None:
            block.data.append(line)
    if block is not None:
        yield block


def tokens(line: Line) -> list[str]:
    """The comma-separated fields of a data line (empty fields dropped)."""
    return [t.strip() for t in line.text.split(",") if t.strip()]


class SetNames(dict):
    """Named sets ``{NAME: indices}`` with case-insensitive look-up (ccx upper-cases names)."""

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and super().__contains__(name.upper())

    def __getitem__(self, name: str):
        return super().__getitem__(name.upper())


@dataclass
class InpMesh:
    """Nodes (ids (N,), points (N, 3)), element blocks ``[(ccx type, ids (E,), conn (E, k) node ids)]`` and
    named node sets ``{NAME: node indices}`` (positions in ``node_ids``)."""

    node_ids: np.ndarray
    points: np.ndarray
    blocks: list[tuple[str, np.ndarray, np.ndarray]]
    node_sets: dict[str, np.ndarray] = field(default_factory=dict)
    element_sets: dict[str, list[int]] = field(default_factory=dict)
    #: facet elements read beside the solids (``{type: count}``, :data:`FACET_TYPES`): sets only, no model
    facets: dict[str, int] = field(default_factory=dict)
    #: element types of the file read as another (``{file's type: type read}``, :data:`VARIANTS`)
    renamed: dict[str, str] = field(default_factory=dict)


class InpModel:
    """The nodes, solid elements and sets of ``.inp`` blocks (see the module docstring); ``facets``: take the
    elements of :data:`FACET_TYPES` as facets (their nodes name sets) instead of refusing them."""

    def __init__(self, top: Path, *, facets: bool = False):
        self.top = Path(top)
        self.take_facets = facets
        self.nodes: dict[int, list[float]] = {}
        self.elements: dict[str, list[list[int]]] = {}
        self.facets: dict[str, list[list[int]]] = {}
        self.facet_heads: dict[str, Line] = {}  # the first *ELEMENT line of each facet type
        self.renamed: dict[str, str] = {}  # variants read as their base type (:data:`VARIANTS`)
        self.element_lines: dict[int, Line] = {}
        self.nsets: dict[str, list[int]] = {}
        self.elsets: dict[str, list[int]] = {}

    def error(self, line: Line | None, message: str) -> InpError:
        return InpError(self.top, line, message)

    def add(self, block: Block) -> bool:
        """Take ``block`` if it is a ``*NODE``, ``*ELEMENT``, ``*NSET`` or ``*ELSET``; False otherwise."""
        if block.name == "NODE":
            self._nodes(block)
        elif block.name == "ELEMENT":
            self._elements(block)
        elif block.name in ("NSET", "ELSET"):
            self._set(block)
        else:
            return False
        return True

    def _nodes(self, block: Block) -> None:
        ids = []
        for line in block.data:
            v = tokens(line)
            try:
                if len(v) < 2:
                    raise ValueError("no coordinates")
                nid = int(v[0])
                xyz = [float(x) for x in v[1:4]]
            except ValueError as exc:
                raise self.error(line, f"expected 'node id, x, y, z', got {line.text[:60]!r} ({exc})") from None
            self.nodes[nid] = xyz + [0.0] * (3 - len(xyz))
            ids.append(nid)
        if "NSET" in block.options:
            self.nsets.setdefault(block.options["NSET"].upper(), []).extend(ids)

    def _elements(self, block: Block) -> None:
        etype = block.options.get("TYPE", "").upper()
        if self.take_facets and etype in VARIANTS:
            self.renamed[etype], etype = VARIANTS[etype], VARIANTS[etype]
        if etype in REFUSED_TYPES:
            raise self.error(block.head, f"element type {etype!r} is not supported: {REFUSED_TYPES[etype]}")
        facet = self.take_facets and etype in FACET_TYPES
        if etype not in SOLID_TYPES and not facet:
            raise self.error(block.head, f"element type {etype!r} is not supported (3D solid elements only: no "
                                         f"shell, beam, truss or spring elements). Pick one of {sorted(SOLID_TYPES)}")
        n_nodes = FACET_TYPES[etype] if facet else SOLID_TYPES[etype]
        rows = (self.facets if facet else self.elements).setdefault(etype, [])
        if facet:
            self.facet_heads.setdefault(etype, block.head)
        ids = []
        pending: list[Line] = []
        for line in block.data:
            pending.append(line)
            if line.text.endswith(","):
                continue
            try:
                vals = [int(t) for t in " ".join(p.text for p in pending).replace(",", " ").split()]
            except ValueError as exc:
                raise self.error(pending[0], f"expected integer element and node ids ({exc})") from None
            if len(vals) != n_nodes + 1:
                raise self.error(pending[0], f"a {etype} element needs {n_nodes} nodes, got "
                                             f"{len(vals) - 1}")
            rows.append(vals)
            ids.append(vals[0])
            self.element_lines[vals[0]] = pending[0]
            pending = []
        if pending:
            raise self.error(pending[0], "the element's line ends with a comma but no line follows before the next "
                                         "keyword or the end of the file (a truncated file?)")
        if "ELSET" in block.options:
            self.elsets.setdefault(block.options["ELSET"].upper(), []).extend(ids)

    def _set(self, block: Block) -> None:
        kind = block.name  # NSET or ELSET
        name = block.options.get(kind, "").upper()
        if not name:
            raise self.error(block.head, f"*{kind} without {kind}=<name>")
        known = self.nsets if kind == "NSET" else self.elsets
        members = known.setdefault(name, [])
        what = "node" if kind == "NSET" else "element"
        for line in block.data:
            if "GENERATE" in block.options:
                try:
                    r = [int(t) for t in tokens(line)]
                    if len(r) not in (2, 3) or (len(r) == 3 and r[2] <= 0) or r[1] < r[0]:
                        raise ValueError
                except ValueError:
                    raise self.error(line, f"*{kind}, GENERATE: expected 'first, last[, increment]' with first <= "
                                           f"last and a positive increment, got {line.text[:60]!r}") from None
                members.extend(range(r[0], r[1] + 1, r[2] if len(r) == 3 else 1))
                continue
            for t in tokens(line):
                try:
                    members.append(int(t))
                except ValueError:
                    if t.upper() not in known:
                        raise self.error(line, f"*{kind} {name}: {t!r} is neither a {what} number nor a {what} set "
                                               f"defined before") from None
                    members.extend(known[t.upper()])

    def mesh(self) -> InpMesh:
        """The checked mesh (:func:`stepnf.geometry.checks.check_volume_mesh`) and its named node sets."""
        blocks = {t: rows for t, rows in self.elements.items() if rows}
        if not blocks:
            only = [t for t, r in self.facets.items() if r]
            if only:  # a shell or beam model: refused as without facets, at its first element block
                raise self.error(self.facet_heads[only[0]], f"element type {only[0]!r} is not supported (3D solid "
                                 "elements only: surface and line elements are taken, as sets of nodes, only beside "
                                 f"solid ones). Pick one of {sorted(SOLID_TYPES)}")
            raise self.error(None, f"no elements: no *ELEMENT block of a solid type {sorted(SOLID_TYPES)} with "
                                   "elements in it")
        if not self.nodes:
            raise self.error(None, "no nodes: no *NODE block with nodes in it")
        out_blocks = []
        for t, rows in blocks.items():
            a = np.array(rows, dtype=np.int64)
            out_blocks.append((t, a[:, 0], a[:, 1:]))
        used = np.unique(np.concatenate([c.ravel() for _, _, c in out_blocks]))
        defined = np.array(sorted(self.nodes), dtype=np.int64)
        missing = np.setdiff1d(used, defined)
        if missing.size:
            for t, eids, conn in out_blocks:
                bad = ~np.isin(conn, defined)
                if bad.any():
                    e = int(np.nonzero(bad.any(axis=1))[0][0])
                    raise self.error(None, f"{t} element {int(eids[e])} uses node {int(conn[e][bad[e]][0])}, which "
                                           f"no *NODE line defines; {missing.size} undefined node(s), e.g. "
                                           f"{missing[:5].tolist()}")
        pts = np.array([self.nodes[int(i)] for i in used], dtype=float)
        check_volume_mesh(pts, [(MESHIO_TYPES[t], np.searchsorted(used, c)) for t, _, c in out_blocks],
                          source=self.top, node_ids=used, cell_ids=[e for _, e, _ in out_blocks],
                          cell_labels=[f"{t} element" for t, _, _ in out_blocks])
        facets = [(t, np.array(r, dtype=np.int64)) for t, r in self.facets.items() if r]
        facet_blocks = [(t, a[:, 0], a[:, 1:]) for t, a in facets]
        return InpMesh(used, pts, out_blocks, self.node_sets(used, out_blocks + facet_blocks), dict(self.elsets),
                       {t: int(len(a)) for t, a in facets}, dict(self.renamed))

    def node_sets(self, used: np.ndarray, blocks: list[tuple[str, np.ndarray, np.ndarray]]) -> SetNames:
        """``{NAME: positions in used}``: the used nodes of every *NSET, and of the elements (``blocks``: solids
        and facets) of every *ELSET that no *NSET names (ids that are no used node carry no dof and are left
        out)."""
        out = SetNames()
        for name, ids in self.nsets.items():
            ids = np.asarray(ids, dtype=np.int64)
            out[name] = np.flatnonzero(np.isin(used, ids))
        for name, members in self.elsets.items():
            if name not in out:
                m = np.asarray(members, dtype=np.int64)
                nodes = np.concatenate([c[np.isin(e, m)].ravel() for _, e, c in blocks])
                out[name] = np.flatnonzero(np.isin(used, nodes))
        return out


def read_inp_mesh(path: str | Path, *, facets: bool = True) -> InpMesh:
    """The solid mesh of the ``.inp`` file ``path`` (the ``mesh`` key of both solver routes).

    Only the mesh and its named sets are taken: every ``*NODE`` line, every ``*ELEMENT`` block of a solid
    type (``C3D*``), the ``*NSET`` and ``*ELSET`` sets, and (``facets``) the surface and line elements of
    :data:`FACET_TYPES` as sets of nodes (:attr:`InpMesh.facets` counts them: the caller says so), the Abaqus
    variants of :data:`VARIANTS` as their base type;
    materials, sections, boundary conditions and steps are ignored. ``*INCLUDE`` is followed (relative to
    the file's folder); continuation lines of ``*ELEMENT`` (a line ending with a comma) are joined; nodes
    that no solid element uses are dropped (they would carry no stiffness). The nodes and elements found
    are checked by :func:`stepnf.geometry.checks.check_volume_mesh` (NaN coordinates, undefined nodes,
    flat meshes, coincident nodes, degenerate, tangled or overlapping elements). Raises
    :class:`~stepnf.errors.MeshError` (a ``ValueError``) naming the file, the line, or the element or
    node (the file's ids) at fault.
    """
    path = Path(path)
    if not path.is_file():
        raise MeshError(path, f"mesh file {path} does not exist")
    model = InpModel(path, facets=facets)
    for block in keyword_blocks(inp_lines(path)):
        model.add(block)
    return model.mesh()


def facets_note(mesh: InpMesh, source: str | Path) -> str:
    """One line saying what :func:`read_inp_mesh` did with the facet elements of ``mesh`` ('' when none)."""
    if not mesh.facets:
        return ""
    what = ", ".join(f"{n} {t}" for t, n in mesh.facets.items())
    return (f"{source}: {what} surface/line element(s) beside the solids are no part of the model (ignored); "
            "their named sets (*ELSET, Gmsh physical group) name node sets, usable in [[model.boundary]]")
