"""Implementation of the ``code_aster`` adapter (see the package docstring for the scene keys).

Materials (``[model.material]``, ``[model.materials.<MED cell group>]``, :mod:`.materials`): the
keywords were checked against code_aster's own sources (the Krande/code-aster-copy mirror of
code_aster 17, 2025):

- ``code_aster/Cata/Commands/defi_materiau.py``: ``ELAS_ORTH`` takes ``E_L``, ``E_T``, ``NU_LT``,
  ``G_LT`` (required), ``E_N``, ``NU_LN``, ``NU_TN``, ``G_LN``, ``G_TN``, ``RHO`` (optional); stepnf
  writes all ten (axes 1, 2, 3 = L, T, N; ``NU_LT`` = nu12 is taken as -eps_T/eps_L under a stress
  along L, code_aster's documented convention, not re-derived from its Fortran here).
- ``code_aster/Cata/Commands/affe_materiau.py``: ``AFFE`` (``max='**'``) with one of ``TOUT``,
  ``GROUP_MA``, ``MAILLE`` and ``MATER``; stepnf gives the default ``TOUT="OUI"`` first and then
  each group (a later occurrence overrides an earlier one on the same cells, as for every carte).
- ``code_aster/Cata/Commands/affe_cara_elem.py``: ``MASSIF`` with one of ``GROUP_MA``/``TOUT`` and
  ``ANGL_REP`` (3 angles in 3D); ``bibfor/modelisa/aceama.F90`` first puts zero angles on the whole
  mesh and then processes only ``GROUP_MA`` and ``MAILLE`` (``TOUT`` is accepted by the catalogue
  but not read there), so a default material with axes gets a group ``STEPNF_ALL`` made by
  ``DEFI_GROUP(CREA_GROUP_MA=_F(NOM=..., TOUT="OUI"))`` (``defi_group.py``). The angles are in
  degrees (``r8dgrd`` where ANGL_REP is read, e.g. CALC_POINT_MAT) and follow
  ``bibfor/utilitai/matrot.F90``: alpha about Z0, beta about Y1 in the negative sense, gamma
  about X; the rows of its matrix are the material axes, like :func:`stepnf.plugin.materials.rotation`
  (the test rebuilds that matrix from the angles to 1e-12).
- ``code_aster/Behaviours/elas.py``: the behaviour ``ELAS`` takes ``mc_mater = ('ELAS',
  'ELAS_ORTH', 'ELAS_ISTR')`` with ``deformation`` including ``GROT_GDEP`` in ``3D``: STAT_NON_LINE
  with ``RELATION="ELAS", DEFORMATION="GROT_GDEP"`` stays St Venant-Kirchhoff with orthotropy.
- ``code_aster/Cata/Commands/assemblage.py``: ``ASSEMBLAGE`` takes ``CARA_ELEM``.

Every command and keyword of every rendered variant (both force routes, the materials above,
boundary conditions, the matrices job) passed code_aster 15's own checker
(``code_aster/Cata/Language/SyntaxChecker.py`` ``checkCommandSyntax`` of the ehmoussi/code_aster
mirror, 15.2, 2020); ``tests/data/code_aster_catalogue.json`` keeps those facts, each with its
catalogue file, and ``tests/solvers/code_aster/test_code_aster_catalogue.py`` holds the rendered files to them.
Not in code_aster 15: ``getNodeAndComponentFromDOF`` of the matrix export (>= 16).

Force routes (``force_route``): ``"stat_non_line"`` (``forces.comm``, the default) imposes every
dof of every node by ``AFFE_CHAR_CINE(EVOL_IMPO=...)`` and lets one ``STAT_NON_LINE`` reach each
field, then ``CALC_CHAMP(FORCE="FORC_NODA")``; ``"calcul"`` (``forces_calcul.comm``) asks
``CALCUL`` for ``FORC_INTE_ELEM`` at each field directly (the route of the ROM_for_geomNL
scripts, which ran it in code_aster 13.4): no Newton loop, no tangent matrix, so less work per
field, with the same ``ELAS``/``GROT_GDEP`` internal force. ``CALCUL`` needs the previous
displacement, stress and internal variables for a non-linear option (``calcCalcMeca.F90``,
``CALCUL1_12``): zero fields made by ``CREA_CHAMP``. That route is checked against the catalogue
only; it was never run in code_aster by stepnf.
"""
from __future__ import annotations

import math
import re
import shlex
import shutil
import tempfile
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import scipy.sparse as sp

from stepnf.plugin.boundary import BOUNDARY_KEY
from stepnf.errors import SceneError, SolverRunError
from stepnf.external import (RUN_KEYS, CommandTemplate, ExternalSolverAdapter, SolidFromScene, missing_output,
                             require_files, solid_model_keys)
from stepnf.external.keys import MEMORY_MB, NCPUS
from stepnf.geometry.keys import MATERIAL_KEYS
from stepnf.geometry.solid import CapSolid
from stepnf.plugin.materials import MATERIALS_KEY, Material, assign_cells
from stepnf.runtime.programs import resolve_program, which
from stepnf.keys.schema import Key, Schema

from .materials import has_axes, is_plain, materials_text, python_str
from .med import (MedError, add_nodal_field, read_cell_groups, read_groups, read_mesh_nodes, read_nodal_steps,
                  write_med)

ELEMENTS = ("hex20", "dkt", "coque_3d")  # dkt, coque_3d: shells on a user's MED mid-surface mesh (.shell)
TEMPLATE_NAMES = ("forces.comm", "forces.export", "matrices.comm", "matrices.export", "forces_calcul.comm",
                  "forces_shell.comm", "matrices_shell.comm")
#: ``force_route`` -> the template of the force job (written as ``forces.comm`` in the work folder)
FORCE_ROUTES = {"stat_non_line": "forces.comm", "calcul": "forces_calcul.comm"}
COMPONENTS = ("DX", "DY", "DZ")
#: Default command; ``${export}`` and ``${workdir}`` are filled in. A docker image works too, e.g.
#: ``docker run --rm -v ${workdir}:${workdir} IMAGE run_aster ${export}``.
DEFAULT_COMMAND = "run_aster ${export}"
MED_SUFFIXES = (".med", ".rmed", ".mmed")
#: Scene keys of ``[model]`` (besides ``solver``; ``stepnf solvers --keys code_aster``).
MODEL_KEYS = Schema(
    *solid_model_keys(ELEMENTS, MED_SUFFIXES, "a user's MED volume mesh"),
    Key("mesh_name", "text", "name of the mesh inside the MED file (default: its first mesh)", what="a mesh name"),
    Key("templates", "folder", f"a folder of templates overriding the shipped ones (any of {list(TEMPLATE_NAMES)}; "
        "Python run by code_aster: only with --allow-programs)", what="a template folder name"),
    Key("command", "text", "the command running one job; ${export} and ${workdir} are filled in (a command the "
        "scene names runs only with --allow-programs)", default=DEFAULT_COMMAND, what="a command"),
    Key("version", "text", "code_aster version of the .export file", default="stable", what="a version name"),
    Key("force_route", "choice", "how code_aster computes the internal forces: one STAT_NON_LINE with every dof "
        "imposed (EVOL_IMPO), or CALCUL FORC_INTE_ELEM per field (one element loop, no Newton iteration; checked "
        "against code_aster's catalogue only, never run by stepnf)", default="stat_non_line",
        choices=tuple(FORCE_ROUTES)),
    Key("thickness", "number", "shell thickness (m; AFFE_CARA_ELEM COQUE EPAIS): element = \"dkt\" or \"coque_3d\" "
        "with a MED mesh of the mid-surface", lo=0.0, lo_open=True),
    NCPUS, MEMORY_MB, *RUN_KEYS, BOUNDARY_KEY, MATERIALS_KEY,
)
FIELD_IN, FIELD_OUT = "U", "F"
REAL = "%.17g"
#: Values the command files hold as Python strings: each also given as ``${<name>_py}``, a Python string
#: literal of it quotes included (:func:`.materials.python_str`), which the shipped templates use.
PY_STRINGS = ("mesh_name", "field_in", "field_out", "workdir", "matrices_file", "export")
#: A folder the .export file can name: its lines are split at spaces (``F comm <path> D 1``), so no space,
#: quote, backslash or control character.
EXPORT_PATH = r"[^\s\"'\\\x00-\x1f\x7f]+"


def shipped_template(name: str) -> CommandTemplate:
    """A template shipped with the adapter (``templates/code_aster/<name>`` of the source tree)."""
    res = resources.files("stepnf_code_aster").joinpath("templates", name)
    return CommandTemplate(res.read_text(encoding="utf-8"), source=f"stepnf_code_aster/templates/{name}")


def export_folder_problem(folder: str | Path) -> str:
    """'' when the .export and command files can name files in ``folder``, else what is wrong with it."""
    if re.fullmatch(EXPORT_PATH, str(folder)):
        return ""
    return (f"{str(folder)!r}: code_aster's .export file names the work files by their paths and splits its lines "
            "at spaces, so the folder's path may hold no space, quote, backslash or control character")


def _plain(value: str, key: str, what: str, pattern: str) -> None:
    """A ValueError naming ``key`` unless ``value`` matches ``pattern``: a value written into the command
    files (Python run by code_aster) or the .export file cannot add code or lines to them."""
    if not re.fullmatch(pattern, value):
        raise ValueError(f"{key} {value!r}: expected {what}, without quotes, backslashes or control characters")


def triplets_to_matrix(values, rows, cols, n: int) -> sp.csr_matrix:
    """Sparse (n, n) from 0-based triplets; one stored triangle of a symmetric matrix is mirrored."""
    values = np.asarray(values, float)
    rows = np.asarray(rows, np.int64)
    cols = np.asarray(cols, np.int64)
    if values.size and (np.all(rows >= cols) or np.all(rows <= cols)):
        off = rows != cols
        rows, cols, values = (np.concatenate([rows, cols[off]]), np.concatenate([cols, rows[off]]),
                              np.concatenate([values, values[off]]))
    return sp.csr_matrix((values, (rows, cols)), shape=(n, n))




def load_matrices_npz(path: Path) -> tuple[int, np.ndarray, list[str], sp.csr_matrix, sp.csr_matrix]:
    """The matrices file the matrices template writes: ``(n_eq, dof_nodes, dof_components, K, M)``, the
    equations' node numbers (0-based) and component names (``DX``, ..., ``DRZ``) and K, M over the equations."""
    with np.load(path, allow_pickle=False) as z:
        n_eq = int(z["n"])
        nodes = np.asarray(z["dof_nodes"], dtype=np.int64)
        comps = [str(c).strip() for c in z["dof_components"]]
        K = triplets_to_matrix(z["K_values"], z["K_rows"], z["K_cols"], n_eq)
        M = triplets_to_matrix(z["M_values"], z["M_rows"], z["M_cols"], n_eq)
    return n_eq, nodes, comps, K, M

class CodeAsterAdapter(SolidFromScene, CapSolid, ExternalSolverAdapter):
    """A solid model run by code_aster as a black box (``run_aster`` or a docker image).

    Dofs: ``DX, DY, DZ`` of every node of the MED mesh, node by node (dof
    ``3 i + d``); nothing constrained (free structures). Forces come back
    from MED in float64 (full precision), K and M from an ``.npz`` export.

    Parameters
    ----------
    points : (N, 3) node coordinates of the mesh
    material : ``{"E", "nu", "rho"}`` (``{}`` when ``materials`` holds no isotropic default)
    materials : ``{None: default, MED cell group: Material}`` (:func:`stepnf.plugin.materials.materials`): a
        material per named group of volume cells of the MED mesh, isotropic or orthotropic
        (:meth:`apply_materials`)
    cell_groups : ``(n_cells, {group: 0-based volume cells})`` of the mesh (:func:`.med.read_cell_groups`)
    mesh_file : a user's MED mesh (copied into each work folder) or ``None``
    cells, cell_type : the mesh to write when ``mesh_file`` is ``None`` (VTK order)
    mesh_name : name of the mesh inside the MED file
    templates : folder with user templates overriding the shipped ones (any of
        ``forces.comm``, ``forces.export``, ``matrices.comm``, ``matrices.export``)
    command : command template (``${export}``, ``${workdir}``)
    version, ncpus, memory_mb : ``.export`` parameters
    geometry, midsurface : as for the other shell adapters (scales, Gamma)
    executable, timeout, workdir, keep : see :class:`stepnf.external.ExternalSolverAdapter`
    """

    name = "code_aster"
    program = "run_aster"
    #: :class:`.shell.CodeAsterShellAdapter` (``element = "dkt"``, ``"coque_3d"``), set when the package imports it
    shell_class: Any = None
    model_keys = MODEL_KEYS
    program_keys = {"command": "is the command stepnf would run for every code_aster job",
                    "templates": "names command files that code_aster would run (they are Python programs)"}

    def __init__(self, points: np.ndarray, *, material: Mapping[str, float], cells: np.ndarray | None = None,
                 cell_type: str = "hexahedron20", mesh_file: str | Path | None = None, mesh_name: str = "mesh",
                 templates: str | Path | None = None, command: str = DEFAULT_COMMAND, version: str = "stable",
                 ncpus: int = 1, memory_mb: int = 4096, geometry: Mapping[str, Any] | None = None,
                 midsurface: np.ndarray | None = None, node_sets: Mapping[str, np.ndarray] | None = None,
                 materials: Mapping[str | None, Material] | None = None,
                 cell_groups: tuple[int, Mapping[str, np.ndarray]] | None = None, force_route: str = "stat_non_line",
                 **run: Any):
        cmd = CommandTemplate(command, source="[model] command")
        if not cmd.text.split():
            raise ValueError("empty code_aster command")
        run.setdefault("executable", shlex.split(command)[0])
        super().__init__(**run)
        _plain(mesh_name, "mesh_name", "the mesh's name (written into the command files, which are Python)",
               r"[^\x00-\x1f\x7f\"'\\]+")
        _plain(version, "version", "a code_aster version name (a line of the .export file)", r"[A-Za-z0-9_.+-]+")
        problem = export_folder_problem(self.workdir if self.workdir is not None else tempfile.gettempdir())
        if problem and self.workdir is not None:
            raise SceneError(None, "model.workdir", problem)  # build_solid adds the scene file
        if problem:
            raise ValueError(f"the temporary folder {problem}; it holds the work folders when no [model] workdir is "
                             "given: set TMPDIR or [model] workdir to another folder")
        self.points = np.asarray(points, dtype=float)
        self.cells = None if cells is None else np.asarray(cells, dtype=np.int64)
        self.cell_type = cell_type
        self.mesh_file = None if mesh_file is None else Path(mesh_file)
        if self.mesh_file is None and self.cells is None:
            raise ValueError("give either a MED mesh file or cells to write")
        self.mesh_name = mesh_name
        self.material = {k: float(material[k]) for k in MATERIAL_KEYS if k in material}
        if materials is None and len(self.material) < len(MATERIAL_KEYS):
            raise ValueError(f"code_aster needs the material's {list(MATERIAL_KEYS)}, got {sorted(material)}")
        self.command = cmd
        self.export_values = {"version": version, "ncpus": int(ncpus), "memory_mb": int(memory_mb)}
        if force_route not in FORCE_ROUTES:
            raise ValueError(f"force_route {force_route!r}: pick one of {list(FORCE_ROUTES)}")
        self.force_route = force_route
        self.templates = {name: self._template(name, templates) for name in TEMPLATE_NAMES}
        self.geometry = dict(geometry or {})
        self.midsurface = None if midsurface is None else np.asarray(midsurface, dtype=bool)
        self.node_sets = dict(node_sets or {})
        self._K: sp.csr_matrix | None = None
        self._M: sp.csr_matrix | None = None
        self.hex20_cells = self.cells if cell_type == "hexahedron20" else None
        self.timings: dict[str, float] = {}
        self.cell_groups = cell_groups if cell_groups is not None else (0 if self.cells is None else len(self.cells), {})
        #: ``${materials}`` and ``${cara_elem}`` of the command templates (:mod:`.materials`)
        self.materials: dict[str | None, Material] = {}
        self.material_lines = ("", "")
        if materials:
            self.apply_materials(materials)
        elif self.material:
            from stepnf.plugin.materials import material as checked_material

            self.apply_materials({None: checked_material(self.material, None, "model.material")})
        filled = self._values(Path("workdir"), "forces")
        unfilled = [name for name in self.command.placeholders if name not in filled]
        if unfilled:  # found now, not when the first job is rendered (after the mesh is built and written)
            raise ValueError(f"command: placeholder(s) {unfilled} that stepnf does not fill; it fills {sorted(filled)}")

    def apply_materials(self, materials: Mapping[str | None, Material], *, scene_file: Any = None) -> None:
        """One material per named group of volume cells of the MED mesh (``[model.materials.<group>]``), the
        default (``None``) on the others: SceneErrors naming the key for a group the mesh lacks (listing its
        groups), a cell in two groups, cells in none without a default (:func:`stepnf.plugin.materials.assign_cells`),
        and for regions, orthotropy or axes that a user's template cannot hold (no ``${materials}``,
        no ``${cara_elem}``)."""
        named = [k for k in materials if k is not None]
        if named:
            n_cells, groups = self.cell_groups
            assign_cells(n_cells, groups, named, None in materials, scene_file, self.mesh_file)
        if not is_plain(materials):
            key = "model.materials" if named else "model.material"
            asked = "[model.materials] regions" if named else "an orthotropic [model.material]"
            for job in (self._comm("forces"), "matrices.comm"):
                have = self.templates[job].placeholders
                if "materials" not in have:
                    raise SceneError(scene_file, key, f"the template {self.templates[job].source} has no ${{materials}} "
                                     f"placeholder, so it cannot hold {asked}: put a line ${{materials}} where its "
                                     "DEFI_MATERIAU and AFFE_MATERIAU stand (stepnf writes them, and defines cara)")
                if has_axes(materials) and "cara_elem" not in have:
                    raise SceneError(scene_file, key, f"the template {self.templates[job].source} has no "
                                     "${cara_elem} placeholder for the material axes: end its CHAM_MATER=fieldmat, "
                                     "line with ${cara_elem} (stepnf writes CARA_ELEM=cara there)")
        self.materials = dict(materials)
        default = materials.get(None)
        self.material = ({k: float(default.constants[k]) for k in MATERIAL_KEYS}
                         if default is not None and default.isotropic else {})
        self.material_lines = materials_text(self.materials)

    def _comm(self, job: str) -> str:
        """The template name of ``<job>.comm`` (the force job follows ``force_route``)."""
        return FORCE_ROUTES[self.force_route] if job == "forces" else f"{job}.comm"

    @classmethod
    def validate_config(cls, config: Mapping[str, Any], *, base_dir: str | Path,
                        scene_file: str | Path | None = None) -> dict[str, Any]:
        """The ``[model]`` keys (:func:`stepnf.external.check_solid_config`); ``command`` and ``templates``
        only when the user allows programs (:mod:`stepnf.runtime.programs`); the command's program, when a
        relative path, is the scene folder's (passed on as ``executable``). A shell's conditions take
        rotations (:meth:`rotational_dofs`)."""
        c = super().validate_config(config, base_dir=base_dir, scene_file=scene_file)
        if "command" in config:
            try:
                words = shlex.split(c["command"])
            except ValueError as exc:
                raise SceneError(scene_file, "model.command", f"cannot split the command into words: {exc}") from None
            if not words:
                raise SceneError(scene_file, "model.command", "an empty command; give e.g. \"run_aster ${export}\"")
            c["executable"] = resolve_program(words[0], base_dir)
        if cls.shell_class is not None:
            cls.shell_class.check_shell_keys(c, scene_file)  # element = "dkt" or "coque_3d": mesh and thickness
        return c

    @classmethod
    def rotational_dofs(cls, config: Mapping[str, Any]) -> bool:
        """A shell's nodes (``element = "dkt"``, ``"coque_3d"``: :mod:`.shell`) have rotations ``rx ry rz``."""
        return cls.shell_class is not None and cls.shell_class.takes_rotations(config)

    @staticmethod
    def _template(name: str, folder: str | Path | None) -> CommandTemplate:
        if folder is not None and (Path(folder) / name).is_file():
            return CommandTemplate.from_file(Path(folder) / name)
        return shipped_template(name)

    # ------------------------------------------------------------- builders
    @classmethod
    def from_volume_mesh(cls, mesh: Any, **kw: Any) -> "CodeAsterAdapter":
        """From a :class:`stepnf.geometry.VolumeMesh` (hexahedron20)."""
        if mesh.cell_type != "hexahedron20":
            raise ValueError(f"cell type {mesh.cell_type!r} not supported here. Pick one of ['hexahedron20']")
        kw.setdefault("midsurface", getattr(mesh, "midsurface", None))
        kw.setdefault("node_sets", getattr(mesh, "node_sets", None))
        return cls(mesh.points, cells=mesh.cells, cell_type=mesh.cell_type, **kw)

    @classmethod
    def from_med(cls, path: str | Path, *, mesh_name: str | None = None, shell: str | None = None,
                 **kw: Any) -> "CodeAsterAdapter":
        """A user's MED volume mesh; with ``shell`` (``"dkt"``, ``"coque_3d"``) and ``thickness`` a mid-surface
        mesh of shells (:class:`.shell.CodeAsterShellAdapter`)."""
        from .med import mesh_name as first_mesh

        name = mesh_name or first_mesh(path)
        if shell is not None:  # the shell adapter (.shell) registers itself as shell_class
            return cls.shell_class.from_shell_med(path, name, shell, **kw)
        return cls(read_mesh_nodes(path, name), mesh_file=path, mesh_name=name, node_sets=read_groups(path, name),
                   cell_groups=read_cell_groups(path, name), **kw)

    from_mesh_file = from_med  # the ``mesh`` key (SolidFromScene)

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d.update(solver="code_aster", command=self.command.text, n_nodes=int(len(self.points)),
                 force_route=self.force_route, material=self.material, solver_runs=len(self.runs),
                 geometry={k: (str(v) if isinstance(v, float) and math.isinf(v) else v)
                           for k, v in self.geometry.items()},
                 templates={k: t.source for k, t in self.templates.items()})
        if self.materials and not is_plain(self.materials):
            d["materials"] = {"default" if k is None else k: dict(m.constants) for k, m in self.materials.items()}
        if self.free_dofs is not None:
            d["boundary"] = {"conditions": list(self.applied_conditions), **self.free_dofs.describe()}
        return d

    # ----------------------------------------------------------------- jobs
    def _values(self, workdir: Path, job: str, n_fields: int = 0) -> dict[str, Any]:
        """The placeholders' values for ``job`` run in ``workdir``; ``${<name>_py}`` for the names of
        :data:`PY_STRINGS`. A work folder the .export file cannot name is a SolverRunError."""
        problem = export_folder_problem(workdir)
        if problem:
            raise SolverRunError(f"code_aster work folder {problem}", workdir=workdir)
        vals: dict[str, Any] = {
            "mesh_name": self.mesh_name, "field_in": FIELD_IN, "field_out": FIELD_OUT,
            "n_fields": int(n_fields), "max_iterations": 10, "workdir": str(workdir),
            "matrices_file": str(workdir / "matrices.npz"), "export": str(workdir / f"{job}.export"),
            "time_limit": int(self.timeout) if self.timeout else 86400,
            **{k: REAL % v for k, v in self.material.items()}, **self.export_values,
            "materials": self.material_lines[0], "cara_elem": self.material_lines[1],
        }
        vals.update({f"{k}_py": python_str(vals[k]) for k in PY_STRINGS})
        return vals

    def _write_model(self, workdir: Path, U: np.ndarray | None = None) -> None:
        target = workdir / "model.med"
        steps = None
        if U is not None:
            n = len(self.points)
            steps = [(0.0, np.zeros((n, 3)))] + [(float(i + 1), self.nodal(u)) for i, u in enumerate(U)]
        if self.mesh_file is not None:
            shutil.copyfile(self.mesh_file, target)
            if steps is not None:
                add_nodal_field(target, FIELD_IN, COMPONENTS, steps, mesh_name=self.mesh_name)
        else:
            write_med(target, self.points, self.cells, self.cell_type, mesh_name=self.mesh_name,
                      fields=None if steps is None else {FIELD_IN: (COMPONENTS, steps)})

    def render_job(self, workdir: Path, job: str, n_fields: int = 0) -> list[str]:
        """Write ``<job>.comm`` and ``<job>.export`` into ``workdir``; return the command."""
        vals = self._values(workdir, job, n_fields)
        (workdir / f"{job}.comm").write_text(self.templates[self._comm(job)].render(vals))
        (workdir / f"{job}.export").write_text(self.templates[f"{job}.export"].render(vals))
        # each value one shell word, whatever its characters (a work folder with a space stays one argument)
        return shlex.split(self.command.render({k: shlex.quote(str(v)) for k, v in vals.items()}))

    def run(self, argv, workdir, *, log_name="solver.log"):
        """Run the command; a missing executable gets a hint about docker images."""
        exe = self.executable
        if (which(exe) is None) if "/" not in exe else not Path(exe).is_file():
            raise SolverRunError(
                f"code_aster command {exe!r} not found: install code_aster (run_aster on PATH) or "
                f"run it from an image with [model] command = \"docker run --rm -v ${{workdir}}:${{workdir}} "
                f"<code_aster image> run_aster ${{export}}\" and --allow-programs (a command the scene names runs "
                "only when you allow it)", workdir=workdir)
        return super().run(argv, workdir, log_name=log_name)

    def write_force_job(self, workdir: Path, U: np.ndarray) -> list[str]:
        self._write_model(workdir, U)
        return self.render_job(workdir, "forces", len(U))

    def force_steps(self, workdir: Path) -> list:  # the steps of forces.rmed (or a missing-output error)
        (rmed,) = require_files(workdir, ["forces.rmed"], log=workdir / "solver.log", what="code_aster")
        try:
            return read_nodal_steps(rmed, FIELD_OUT)
        except MedError as exc:
            raise missing_output(workdir, f"code_aster output incomplete: {exc}") from None

    def read_forces(self, workdir: Path, m: int) -> np.ndarray:
        by_time = {int(round(s.time)): s for s in self.force_steps(workdir) if abs(s.time - round(s.time)) < 1e-9}
        n = len(self.points)
        F = np.empty((m, 3 * n))
        for i in range(1, m + 1):
            s = by_time.get(i)
            if s is None:
                raise missing_output(workdir, f"forces.rmed: field {FIELD_OUT!r} has no step at time {i} "
                                              f"(of {m}); found times {sorted(by_time)[:10]}")
            idx = [s.components.index(c) if c in s.components else -1 for c in COMPONENTS]
            if min(idx) < 0:
                raise missing_output(workdir, f"forces.rmed: field {FIELD_OUT!r} lacks components "
                                              f"{[c for c, j in zip(COMPONENTS, idx) if j < 0]}")
            F[i - 1] = s.full(n)[:, idx].ravel()
        return self.free_part(F)

    def _matrices(self) -> None:
        """One matrix run (LazyMatrices calls it once, and times it as ``timings["matrices"]``)."""
        with self.work_folder(prefix="code_aster-matrices-") as wd:
            self._write_model(wd)
            argv = self.render_job(wd, "matrices")
            rec = self.run(argv, wd)
            (npz,) = require_files(wd, ["matrices.npz"], log=rec.log, what="code_aster")
            K, M = self._read_matrices(npz, wd)
            self._K, self._M = self.free_part(K), self.free_part(M)

    def _read_matrices(self, path: Path, workdir: Path) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        n_eq, nodes, comps, K, M = load_matrices_npz(path)
        code = {c: i for i, c in enumerate(COMPONENTS)}
        index = np.array([3 * nd + code.get(c, -10 ** 9) for nd, c in zip(nodes, comps)], dtype=np.int64)
        n = 3 * len(self.points)  # the solver assembles every nodal dof; fixed ones are removed after
        if n_eq != n or len(index) != n or index.min() < 0 or len(np.unique(index)) != n:
            raise missing_output(workdir, f"matrices.npz: {n_eq} equations ({sorted(set(comps))}), expected "
                                          f"the {n} translations DX DY DZ of {n // 3} nodes and nothing else")
        perm = lambda A: sp.csr_matrix((A.tocoo().data, (index[A.tocoo().row], index[A.tocoo().col])), shape=(n, n))
        return perm(K), perm(M)
