"""A user's own CalculiX deck (the ``deck`` key): its model data as written, its steps replaced by stepnf's.

:func:`read_deck` reads the deck (``*INCLUDE`` files inlined, relative to the
deck's folder) and returns a :class:`UserDeck`: the mesh and its named sets,
the model data to run (the text stepnf includes in its jobs before its own
force and matrix steps), the dofs the deck fixes, and a summary for the
results.

Accepted model data, kept as written:

* ``*HEADING``; ``*NODE`` (``NSET``); ``*ELEMENT`` of 3D solid types (``C3D4``
  ... ``C3D20R``; ``TYPE``, ``ELSET``); ``*NSET`` and ``*ELSET`` (ids, sets
  defined before, ``GENERATE``);
* ``*MATERIAL`` (``NAME``) with ``*ELASTIC`` of ``TYPE`` ``ISO`` (default),
  ``ORTHO``, ``ENGINEERING CONSTANTS`` or ``ANISO`` (one set of 2, 9, 9 or 21
  constants and an optional temperature: temperature tables are refused,
  stepnf's steps are isothermal) and ``*DENSITY``: in large deformation, ccx's
  linear elastic material is St Venant-Kirchhoff (S = C : E), so the internal
  force stays an exact cubic;
* ``*SOLID SECTION`` (``ELSET``, ``MATERIAL``, ``ORIENTATION``) and
  ``*ORIENTATION`` (``NAME``, ``SYSTEM``): every element must lie in exactly
  one solid section whose material has ``*ELASTIC`` and ``*DENSITY``;
* ``*SURFACE`` and ``*AMPLITUDE``: definitions only steps use (inert once the
  steps are gone);
* ``*BOUNDARY`` (``OP``, ``AMPLITUDE``) with zero values: lines ``node or node
  set, first dof[, last dof[, 0]]``, dofs 1 to 3. They become boundary
  conditions (dofs removed from the model stepnf analyses) and leave the text:
  stepnf's steps prescribe every dof themselves. A node that no element uses
  has no dof: a condition on it changes nothing (counted in the summary).

Steps: every ``*STEP ... *END STEP`` block is removed (its procedure, loads and
output requests belong to the user's analysis, not to stepnf's). Its
``*BOUNDARY`` lines are the one exception: supports are often written in the
first step, so zero-valued ones are honoured like those of the model data
(the conditions are their union); a step ``*BOUNDARY, OP=NEW`` (which would
remove conditions) and non-zero values are refused.

Refused, each a :class:`~stepnf.errors.SceneError` naming the deck, the
keyword and its line (exit code 2): every keyword of :data:`REFUSED` (constraints
such as ``*EQUATION``, ``*MPC``, ``*RIGID BODY``, ``*COUPLING``; contact; any
material option but ``*ELASTIC`` and ``*DENSITY``; shell, beam, membrane
sections and discrete elements; shell elements (:data:`SHELL_TYPES`, for the
measured :data:`SHELL_REASON`); initial conditions; ``*TRANSFORM``), shell,
beam and other non-solid element types, unknown keyword options, ``*ELASTIC``
types other than the four, a used material without ``*DENSITY``, non-zero or
non-translational ``*BOUNDARY`` values, and any other model-data keyword
(nothing the deck says is silently dropped).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stepnf.geometry.inp import Block, InpError, InpMesh, InpModel, Line, inp_lines, keyword_blocks, tokens, where

#: The node set stepnf adds (every node an element uses): its force output.
STEPNF_NSET = "STEPNF_NODES"
#: ``*ELASTIC, TYPE=...`` -> number of constants.
ELASTIC_TYPES = {"ISO": 2, "ORTHO": 9, "ENGINEERING CONSTANTS": 9, "ANISO": 21}
#: Model-data keywords kept as written, with the options each may carry (``None``: any).
KEPT: dict[str, tuple[str, ...] | None] = {
    "HEADING": (), "NODE": ("NSET",), "ELEMENT": ("TYPE", "ELSET"), "NSET": ("NSET", "GENERATE"),
    "ELSET": ("ELSET", "GENERATE"), "MATERIAL": ("NAME",), "ELASTIC": ("TYPE",), "DENSITY": (),
    "SOLID SECTION": ("ELSET", "MATERIAL", "ORIENTATION"), "ORIENTATION": ("NAME", "SYSTEM"),
    "SURFACE": None, "AMPLITUDE": None, "BOUNDARY": ("OP", "AMPLITUDE"),
}
_REFUSED_GROUPS = {
    "a constraint between dofs (stepnf takes zero-displacement conditions only)":
        ("EQUATION", "MPC", "RIGID BODY", "COUPLING", "KINEMATIC", "DISTRIBUTING", "DISTRIBUTING COUPLING", "TIE",
         "PRE-TENSION SECTION", "CYCLIC SYMMETRY MODEL"),
    "contact (stepnf's model is a single elastic body)":
        ("CONTACT PAIR", "SURFACE INTERACTION", "SURFACE BEHAVIOR", "FRICTION", "CLEARANCE", "CONTACT DAMPING",
         "GAP CONDUCTANCE", "GAP HEAT GENERATION"),
    "a material behaviour other than linear elasticity (stepnf's model is St Venant-Kirchhoff: *ELASTIC and "
    "*DENSITY only)":
        ("PLASTIC", "HYPERELASTIC", "HYPERFOAM", "DEFORMATION PLASTICITY", "CREEP", "USER MATERIAL",
         "CYCLIC HARDENING", "DAMPING", "EXPANSION", "CONDUCTIVITY", "SPECIFIC HEAT", "DEPVAR",
         "ELECTRICAL CONDUCTIVITY", "MAGNETIC PERMEABILITY", "FLUID CONSTANTS", "SPECIFIC GAS CONSTANT"),
    "a section of non-solid elements (stepnf takes 3D solid elements only)":
        ("SHELL SECTION", "BEAM SECTION", "MEMBRANE SECTION", "BEAM GENERAL SECTION", "USER SECTION",
         "FLUID SECTION"),
    "a discrete element (stepnf takes 3D solid elements only)": ("SPRING", "DASHPOT", "MASS", "GAP", "USER ELEMENT"),
    "an initial state (stepnf starts from the unstressed reference configuration)":
        ("INITIAL CONDITIONS", "INITIAL STRAIN INCREASE"),
    "a local system of nodal dofs (stepnf's dofs are the global ux, uy, uz)": ("TRANSFORM", "TRANSFORMF"),
}
#: Keywords refused wherever they stand outside a step -> why.
REFUSED = {kw: why for why, kws in _REFUSED_GROUPS.items() for kw in kws}
#: CalculiX shell element types, refused in a deck for :data:`SHELL_REASON`.
SHELL_TYPES = ("S3", "S3R", "S4", "S4R", "S6", "S8", "S8R", "STRI3", "STRI65", "S4R5", "S9R5")
#: Why a deck's shells are refused: measured with ccx 2.20 on a flat S3/S4/S8R plate whose shell nodes had all six
#: dofs prescribed (*BOUNDARY 1-6, *STATIC NLGEOM), the probe of tests/solvers/calculix/test_calculix_shell_deck.py
#: (the rigid rotation: S3, S4 and S8 fail from 0.1 degree, S8R from 0.5 degree).
SHELL_REASON = ("CalculiX expands shells into 3D solids, and measured with ccx 2.20 its shell nodes make no "
                "black box stepnf can use: *NODE PRINT RF gives the forces but no moments at prescribed rotations "
                "(dofs 4-6), the K and M it exports are over the expanded solid's nodes (translations only), and "
                "a rigid rotation of 0.5 degree about an in-plane axis does not converge. Model the part with "
                "solid elements (C3D20R), or use solver = \"kratos\" with element = \"dkt\"")
REFUSED["SHELL SECTION"] = f"a shell section: {SHELL_REASON}"
#: Keywords whose data lines are numbers only, with the largest number of lines they take.
NUMERIC_DATA = {"MATERIAL": 0, "SOLID SECTION": 1, "ORIENTATION": 2}
#: Keywords that belong to the *MATERIAL above them.
MATERIAL_OPTIONS = {"ELASTIC", "DENSITY"} | set(
    _REFUSED_GROUPS["a material behaviour other than linear elasticity (stepnf's model is St Venant-Kirchhoff: "
                    "*ELASTIC and *DENSITY only)"])


@dataclass
class UserDeck:
    """A deck read by :func:`read_deck`: ``mesh`` (nodes an element uses, sorted by id; named sets), ``text``
    (the model data stepnf runs, ending with the node set :data:`STEPNF_NSET`), ``fixed`` (sorted dof
    indices ``3 i + d`` the deck's ``*BOUNDARY`` lines fix) and ``summary`` (for the results)."""

    path: Path
    mesh: InpMesh
    text: str
    fixed: np.ndarray
    summary: dict[str, Any] = field(default_factory=dict)


@dataclass
class _Material:
    head: Line
    elastic: str | None = None
    density: float | None = None


def read_deck(path: str | Path) -> UserDeck:
    """Read the deck ``path`` (see the module docstring); an :class:`~stepnf.geometry.inp.InpError` (a SceneError)
    naming the file, the line and the keyword for anything stepnf cannot honour."""
    reader = _DeckReader(Path(path))
    for block in keyword_blocks(inp_lines(Path(path))):
        reader.take(block)
    return reader.finish()


def _numbers(block: Block, err) -> list[float]:
    out = []
    for line in block.data:
        for t in tokens(line):
            try:
                x = float(t)
            except ValueError:
                raise err(line, f"*{block.name}: {t!r} is not a number") from None
            if not np.isfinite(x):
                raise err(line, f"*{block.name}: {t!r} is not a finite number")
            out.append(x)
    return out


class _DeckReader:
    #: keyword -> method reading it (besides the mesh and sets, which :class:`~stepnf.geometry.inp.InpModel` reads)
    handlers = {"MATERIAL": "_material", "ELASTIC": "_elastic", "DENSITY": "_density",
                "SOLID SECTION": "_solid_section", "ORIENTATION": "_orientation"}

    def __init__(self, path: Path):
        self.path = path
        self.model = InpModel(path)
        self.parts: list[str] = []
        self.materials: dict[str, _Material] = {}
        self.material: _Material | None = None
        self.sections: list[tuple[Line, str, str, str | None]] = []
        self.orientations: set[str] = set()
        self.step: dict[str, Any] | None = None
        self.steps: list[dict[str, Any]] = []
        self.conditions: list[tuple[Line, str, int, int]] = []
        self.n_boundary_lines = {"model data": 0, "steps": 0}

    def err(self, line: Line | None, message: str) -> InpError:
        return InpError(self.path, line, message)

    def take(self, b: Block) -> None:
        if self.step is not None:
            self._in_step(b)
            return
        if b.name == "STEP":
            self.step = {"line": b.head.lineno, "where": where(b.head), "procedure": None}
            self.material = None
            self.parts.append(f"** stepnf: the deck's *STEP of {where(b.head)} removed (stepnf runs its own steps)")
            return
        if b.name == "END STEP":
            raise self.err(b.head, "*END STEP without a *STEP before it")
        if b.name in REFUSED:
            raise self.err(b.head, f"*{b.name}: {REFUSED[b.name]}; stepnf cannot honour it. Remove it, or analyse "
                                   "another model")
        if b.name not in KEPT:
            raise self.err(b.head, f"*{b.name}: not a model-data keyword stepnf understands in a deck; it takes "
                                   f"{['*' + k for k in KEPT]} (and removes *STEP ... *END STEP blocks)")
        allowed_options = KEPT[b.name]
        if allowed_options is not None:
            bad = [o for o in b.options if o not in allowed_options]
            if bad:
                raise self.err(b.head, f"*{b.name}: option {bad[0]} is not taken (stepnf takes "
                                       f"{list(allowed_options) or 'no options'} here)")
        if b.name in NUMERIC_DATA:
            if len(b.data) > NUMERIC_DATA[b.name]:
                raise self.err(b.data[NUMERIC_DATA[b.name]], f"*{b.name} takes at most {NUMERIC_DATA[b.name]} data "
                                                             f"line(s); is a keyword line missing its '*'?")
            _numbers(b, self.err)
        if b.name in MATERIAL_OPTIONS and self.material is None:
            raise self.err(b.head, f"*{b.name} outside a *MATERIAL")
        if b.name not in MATERIAL_OPTIONS:
            self.material = None
        if b.name == "BOUNDARY":
            self._boundary(b, in_step=False)
            self.parts.append(f"** stepnf: the *BOUNDARY of {where(b.head)} is a boundary condition of stepnf's "
                              "model (its dofs removed), not written here")
            return
        if b.name == "ELEMENT" and b.options.get("TYPE", "").upper() in SHELL_TYPES:
            raise self.err(b.head, f"element type {b.options['TYPE'].upper()!r} is a shell, refused in a deck: "
                                   f"{SHELL_REASON}")
        if not self.model.add(b) and b.name in self.handlers:
            getattr(self, self.handlers[b.name])(b)
        self.parts.append("\n".join(line.text for line in (b.head, *b.data)))

    # ------------------------------------------------------------ model data
    def _material(self, b: Block) -> None:
        name = b.options.get("NAME", "").upper()
        if not name:
            raise self.err(b.head, "*MATERIAL without NAME=<name>")
        self.material = self.materials[name] = _Material(b.head)

    def _elastic(self, b: Block) -> None:
        kind = " ".join(b.options.get("TYPE", "ISO").upper().split())
        if kind not in ELASTIC_TYPES:
            raise self.err(b.head, f"*ELASTIC, TYPE={kind}: stepnf takes TYPE = {list(ELASTIC_TYPES)} (linear "
                                   "elasticity)")
        if self.material.elastic is not None:
            raise self.err(b.head, "a second *ELASTIC in the same *MATERIAL")
        v = _numbers(b, self.err)
        n = ELASTIC_TYPES[kind]
        if len(v) not in (n, n + 1):
            raise self.err(b.head, f"*ELASTIC, TYPE={kind} takes {n} constants and an optional temperature, got "
                                   f"{len(v)} numbers (temperature tables are refused: stepnf's steps are isothermal)")
        if kind == "ISO" and not (v[0] > 0 and -1.0 < v[1] < 0.5):
            raise self.err(b.head, f"*ELASTIC: E = {v[0]:g}, nu = {v[1]:g}; expected E > 0 and -1 < nu < 0.5")
        self.material.elastic = kind

    def _density(self, b: Block) -> None:
        v = _numbers(b, self.err)
        if len(v) not in (1, 2) or not v[0] > 0:
            raise self.err(b.head, f"*DENSITY takes one positive density (and an optional temperature), got {v}")
        self.material.density = v[0]

    def _solid_section(self, b: Block) -> None:
        elset, material = b.options.get("ELSET", "").upper(), b.options.get("MATERIAL", "").upper()
        if not elset or not material:
            raise self.err(b.head, "*SOLID SECTION needs ELSET=<element set> and MATERIAL=<name>")
        orientation = b.options.get("ORIENTATION")
        self.sections.append((b.head, elset, material, orientation.upper() if orientation else None))

    def _orientation(self, b: Block) -> None:
        self.orientations.add(b.options.get("NAME", "").upper())

    def _boundary(self, b: Block, *, in_step: bool) -> None:
        if b.options.get("OP", "MOD").upper() not in ("MOD", "NEW"):
            raise self.err(b.head, f"*BOUNDARY, OP={b.options['OP']}: expected OP=MOD or OP=NEW")
        if in_step and b.options.get("OP", "MOD").upper() == "NEW":
            raise self.err(b.head, "*BOUNDARY, OP=NEW in a step would remove conditions; stepnf applies the union "
                                   "of the deck's zero-valued conditions: write them without OP=NEW (or in the "
                                   "model data)")
        for line in b.data:
            f = [t.strip() for t in line.text.split(",")]
            while f and not f[-1]:
                f.pop()
            try:
                if len(f) < 2 or len(f) > 4 or not f[0]:
                    raise ValueError
                first = int(f[1])
                last = int(f[2]) if len(f) > 2 and f[2] else first
                value = float(f[3]) if len(f) > 3 else 0.0
            except ValueError:
                raise self.err(line, f"*BOUNDARY: expected 'node or node set, first dof[, last dof[, value]]', got "
                                     f"{line.text[:60]!r}") from None
            if not (1 <= first <= last <= 3):
                raise self.err(line, f"*BOUNDARY: dofs {first} to {last}; stepnf takes dofs 1 to 3 (ux, uy, uz: a "
                                     "solid's nodes have no rotations, stepnf's model no temperature)")
            if value != 0.0:
                raise self.err(line, f"*BOUNDARY: a non-zero prescribed value ({value:g}); stepnf takes homogeneous "
                                     "conditions only (zero displacement): set it to 0 or remove the line")
            self.conditions.append((line, f[0], first, last))
            self.n_boundary_lines["steps" if in_step else "model data"] += 1

    def _in_step(self, b: Block) -> None:
        if b.name == "STEP":
            raise self.err(b.head, f"*STEP inside the *STEP of line {self.step['line']} (no *END STEP between them)")
        if b.name == "END STEP":
            self.steps.append({k: self.step[k] for k in ("line", "procedure")})
            self.step = None
        elif b.name == "BOUNDARY":
            self._boundary(b, in_step=True)
        elif self.step["procedure"] is None:
            self.step["procedure"] = b.name

    # ----------------------------------------------------------------- end
    def finish(self) -> UserDeck:
        if self.step is not None:
            raise self.err(None, f"the *STEP of {self.step['where']} has no *END STEP (a truncated deck?)")
        mesh = self.model.mesh()
        if STEPNF_NSET in self.model.nsets:
            raise self.err(None, f"the node set name {STEPNF_NSET} is stepnf's own; rename the deck's set")
        self._check_sections(mesh)
        fixed, ignored = self._fixed_dofs(mesh)
        ids = mesh.node_ids
        rows = [", ".join(map(str, ids[i:i + 16])) for i in range(0, len(ids), 16)]
        text = "\n".join([*self.parts, "** stepnf: every node an element uses (the force output of stepnf's steps)",
                          f"*NSET, NSET={STEPNF_NSET}", *rows]) + "\n"
        summary = {"deck": str(self.path), "nodes": int(len(ids)),
                   "elements": {t: int(len(e)) for t, e, _ in mesh.blocks},
                   "materials": {n: m.elastic for n, m in self.materials.items()},
                   "solid_sections": len(self.sections), "orientations": len(self.orientations),
                   "boundary_lines": dict(self.n_boundary_lines), "fixed_dofs": int(fixed.size),
                   "boundary_nodes_without_element": ignored, "steps_removed": self.steps}
        return UserDeck(self.path, mesh, text, fixed, summary)

    def _check_sections(self, mesh: InpMesh) -> None:
        if not self.sections:
            raise self.err(None, "no *SOLID SECTION: every element needs one (ELSET=..., MATERIAL=...)")
        all_ids = np.concatenate([e for _, e, _ in mesh.blocks])
        owner = np.full(len(all_ids), -1)
        order = np.argsort(all_ids)
        for k, (head, elset, material, orientation) in enumerate(self.sections):
            if elset not in self.model.elsets:
                raise self.err(head, f"*SOLID SECTION: no element set {elset!r} (sets: "
                                     f"{sorted(self.model.elsets) or 'none'})")
            m = self.materials.get(material)
            if m is None:
                raise self.err(head, f"*SOLID SECTION: no *MATERIAL {material!r} (materials: "
                                     f"{sorted(self.materials) or 'none'})")
            for what, ok in (("*ELASTIC", m.elastic is not None), ("*DENSITY (stepnf needs the mass matrix)",
                                                                    m.density is not None)):
                if not ok:
                    raise self.err(m.head, f"*MATERIAL {material} (used by the *SOLID SECTION of "
                                           f"{where(head)}) has no {what}")
            if orientation is not None and orientation not in self.orientations:
                raise self.err(head, f"*SOLID SECTION: no *ORIENTATION {orientation!r}")
            members = np.asarray(self.model.elsets[elset], dtype=np.int64)
            pos = order[np.clip(np.searchsorted(all_ids[order], members), 0, len(all_ids) - 1)]
            pos = np.unique(pos[all_ids[pos] == members])
            twice = pos[owner[pos] >= 0]
            if twice.size:
                other = self.sections[owner[twice[0]]][0]
                raise self.err(head, f"*SOLID SECTION: element {int(all_ids[twice[0]])} already has the section of "
                                     f"{where(other)}")
            owner[pos] = k
        if np.any(owner < 0):
            e = int(all_ids[np.flatnonzero(owner < 0)[0]])
            raise self.err(self.model.element_lines.get(e), f"element {e} lies in no *SOLID SECTION "
                                                            f"({int(np.sum(owner < 0))} such elements)")

    def _fixed_dofs(self, mesh: InpMesh) -> tuple[np.ndarray, int]:
        pos = {int(n): i for i, n in enumerate(mesh.node_ids)}
        fixed: list[np.ndarray] = []
        ignored = 0
        for line, target, first, last in self.conditions:
            dofs = np.arange(first - 1, last)
            try:
                nid = int(target)
            except ValueError:
                if target.upper() not in self.model.nsets:
                    raise self.err(line, f"*BOUNDARY: no node set {target!r} (node sets: "
                                         f"{sorted(self.model.nsets) or 'none'})") from None
                nodes = mesh.node_sets[target]
                ignored += len(set(self.model.nsets[target.upper()])) - len(nodes)
            else:
                if nid not in self.model.nodes:
                    raise self.err(line, f"*BOUNDARY: node {nid} is not defined by any *NODE line")
                if nid not in pos:
                    ignored += 1
                    continue
                nodes = np.array([pos[nid]])
            fixed.append((3 * nodes[:, None] + dofs[None, :]).ravel())
        out = np.unique(np.concatenate(fixed)) if fixed else np.zeros(0, dtype=np.int64)
        return out.astype(np.int64), int(ignored)
