"""Implementation of the ``calculix`` adapter (see the package docstring for the scene keys)."""
from __future__ import annotations

import math
from importlib import resources
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.plugin.boundary import BOUNDARY_KEY, FreeDofs
from stepnf.errors import SceneError
from stepnf.external import (EXECUTABLE, RUN_KEYS, CommandTemplate, ExternalSolverAdapter, SolidFromScene,
                             missing_output, require_files, solid_model_keys)
from stepnf.external.keys import THREADS
from stepnf.geometry.keys import MATERIAL_KEYS
from stepnf.geometry.solid import CapSolid
from stepnf.plugin.materials import MATERIALS_KEY, Material
from stepnf.runtime.programs import resolve_program
from stepnf.runtime.progress import thousands
from stepnf.keys.schema import Key, Schema

from .deck import CCX_ELEMENTS, REAL, format_boundary, mesh_text
from .inpmesh import MESH_SUFFIXES
from .results import ResultFormatError, read_dat_forces, read_dof, read_matrix
from .sections import Section, assign_sections, is_plain, isotropic_section, materials_text

ELEMENTS = ("hex20",)
#: Scene keys of ``[model]`` (besides ``solver``; ``stepnf solvers --keys calculix``).
MODEL_KEYS = Schema(
    *solid_model_keys(ELEMENTS, MESH_SUFFIXES, "a user's solid mesh: an .inp file (*NODE and *ELEMENT blocks of "
                      "C3D* elements, *NSET and *ELSET sets; surface elements beside them taken as sets) or a Gmsh "
                      ".msh file (physical groups as sets)"),
    Key("deck", "file", "a user's whole CalculiX model (nodes, elements, sets, materials, sections, *BOUNDARY; its "
        "steps are replaced by stepnf's) instead of mesh or [model.geometry]", suffixes=(".inp",),
        what="a CalculiX deck file name"),
    MATERIALS_KEY,
    BOUNDARY_KEY,
    Key("template", "file", "a job template with ${mesh_file}, ${steps} (and ${materials}, ${E}, ${nu}, ${rho}, "
        "${title} if used; ${materials} for [model.materials] or orthotropic constants) instead of the shipped "
        "templates/job.inp or materials_job.inp (not with deck)", what="a job template file name"),
    EXECUTABLE, THREADS, *RUN_KEYS,
)
#: CalculiX solid element types of order 1 (the others are quadratic).
LINEAR_TYPES = ("C3D4", "C3D6", "C3D8", "C3D8R", "C3D8I")
#: Largest number of ``*BOUNDARY`` lines (fields x dofs) in one deck; bigger batches are split over runs.
MAX_BOUNDARY_LINES = 4_000_000


def shipped_template(name: str) -> CommandTemplate:
    """A template shipped with the adapter (``templates/calculix/<name>`` of the source tree)."""
    res = resources.files("stepnf_calculix").joinpath("templates", name)
    return CommandTemplate(res.read_text(encoding="utf-8"), source=f"stepnf_calculix/templates/{name}")



class CalculixAdapter(SolidFromScene, CapSolid, ExternalSolverAdapter):
    """A solid model run by CalculiX ``ccx`` as a black box.

    Dofs: ``ux, uy, uz`` of every node, node by node in the order of
    ``node_ids`` (dof ``3 i + d``), the fixed ones removed when boundary
    conditions fix some (:attr:`free_dofs`, :meth:`apply_boundary`; a free
    structure has the rigid-body modes in the null space of K).

    Constrained dofs: ccx always runs the whole, unconstrained model. Its force
    steps prescribe every dof anyway (the fixed ones at 0), and the matrix and
    tangent runs store K and M of every dof; the adapter then keeps the free
    rows and columns. For homogeneous conditions this is exact: K and M of the
    constrained model are the free-free blocks of the assembled matrices (a ccx
    run with the same ``*BOUNDARY`` in its matrix step stores exactly these
    numbers, bit for bit, and lists only the free dofs in its ``.dof`` file).

    Parameters
    ----------
    node_ids : (N,) CalculiX node numbers
    points : (N, 3) coordinates (model length unit)
    blocks : ``[(ccx element type, element ids (E,), connectivity (E, k) in node ids, ccx order)]``
    material : ``{"E", "nu", "rho"}``: one isotropic material on every element (the shipped template needs a
        material: this one or ``materials``)
    materials : ``{None: default, element set name: Material}`` (:func:`stepnf.plugin.materials.materials`): a material
        per named ``*ELSET`` of ``element_sets``, isotropic or orthotropic (:meth:`apply_materials`)
    element_sets : the mesh's named element sets ``{NAME: element ids}`` (for ``materials``)
    source : the mesh file read (named in messages)
    template : a user's job template (path) instead of the shipped ``job.inp``
    geometry : ``{"shape", "a", "R", "h"}`` for a generated cap (scales, Gamma)
    midsurface : (N,) bool, nodes on the mid-surface (for :meth:`transverse_amplitude`)
    node_sets : named node sets ``{name: node positions}`` (for ``[[model.boundary]] set``)
    deck : a user's deck (:class:`~.userdeck.UserDeck`): its model data is run instead of the mesh and
        the template's material, and the dofs it fixes are removed
    threads : ``OMP_NUM_THREADS`` of the ccx runs (default: the environment's)
    executable, timeout, workdir, keep : see :class:`stepnf.external.ExternalSolverAdapter`
    """

    name = "calculix"
    program = "ccx"
    model_keys = MODEL_KEYS
    program_keys = {"executable": "names the program stepnf would run for every CalculiX job"}
    #: a job template may carry its own material: [model.material] is optional with a mesh
    mesh_needs_material = False
    #: :meth:`tangent_stiffness` and :meth:`sharp_step` are available (14-digit tangents).
    provides_tangent_stiffness = True
    #: the .dat file prints 7 digits: STEP is more precise at larger amplitudes (the force is an
    #: exact cubic for C3D20 with a linear elastic material, so a large amplitude costs nothing)
    step_relative_amplitude = 2.0
    #: forces are read from the .dat file's ``%13.6E`` (results.read_dat_forces)
    force_digits = 7

    def __init__(
        self,
        node_ids: np.ndarray,
        points: np.ndarray,
        blocks: Sequence[tuple[str, np.ndarray, np.ndarray]],
        *,
        material: Mapping[str, float] | None = None,
        materials: Mapping[str | None, Material] | None = None,
        element_sets: Mapping[str, Sequence[int]] | None = None,
        source: str | Path | None = None,
        template: str | Path | None = None,
        geometry: Mapping[str, Any] | None = None,
        midsurface: np.ndarray | None = None,
        node_sets: Mapping[str, np.ndarray] | None = None,
        deck: Any = None,
        threads: int | None = None,
        **run: Any,
    ):
        super().__init__(**run)
        self.node_ids = np.asarray(node_ids, dtype=np.int64)
        self.points = np.asarray(points, dtype=float)
        self.blocks = [(t, np.asarray(e, np.int64), np.asarray(c, np.int64)) for t, e, c in blocks]
        self.material = dict(material or {})
        self.element_sets = element_sets if element_sets is not None else {}
        #: the materials on the elements (``${materials}``); ``None``: the template carries its own
        self.sections: list[Section] | None = None
        if deck is None and all(k in self.material for k in MATERIAL_KEYS):
            self.sections = [isotropic_section(self.material)]
        self.deck = deck
        if deck is not None and template is not None:
            raise ValueError("a deck carries its own model data: give no job template with it")
        self.user_template = template is not None
        default_job = "job.inp" if deck is None else "deck_job.inp"
        self.job_template = CommandTemplate.from_file(template) if template else shipped_template(default_job)
        self.step_template = shipped_template("force_step.inp")
        self.matrix_template = shipped_template("matrix_step.inp")
        self.geometry = dict(geometry or {})
        #: surface and line elements of the mesh file, not modelled (``{type: count}``, :mod:`.inpmesh`)
        self.facets_ignored: dict[str, int] = {}
        self.midsurface = None if midsurface is None else np.asarray(midsurface, dtype=bool)
        self.node_sets = node_sets if node_sets is not None else {}
        self.threads = threads
        self.hex20_cells: np.ndarray | None = None  # set by from_volume_mesh (mid-surface sampling)
        if deck is None:
            self._mesh, self.nset = mesh_text(self.node_ids, self.points, self.blocks), "NALL"
        else:
            from .userdeck import STEPNF_NSET

            self._mesh, self.nset = deck.text, STEPNF_NSET
            self.free_dofs = FreeDofs(self.n_full, deck.fixed) if len(deck.fixed) else None
        self.max_fields_per_run = max(1, MAX_BOUNDARY_LINES // self.n_full)
        self._pos = np.full(int(self.node_ids.max()) + 1, -1)
        self._pos[self.node_ids] = np.arange(len(self.node_ids))
        self._K: sp.csr_matrix | None = None
        self._M: sp.csr_matrix | None = None
        self.timings: dict[str, float] = {}
        if materials:
            self.apply_materials(materials, mesh=source)
        self._check_template()

    def _check_template(self) -> None:
        """The job template's placeholders against what this model gives (a ValueError naming the template)."""
        have = self.job_template.placeholders
        for key in ("mesh_file", "steps"):
            if key not in have:
                raise ValueError(f"{self.job_template.source}: the job template needs the placeholder ${{{key}}}")
        if "materials" in have and self.sections is None:
            raise ValueError(f"{self.job_template.source} writes the scene's materials (${{materials}}); give "
                             "[model.material] (E, nu, rho, or orthotropic constants) or [model.materials.<set>]")
        need = [k for k in MATERIAL_KEYS if k in have and k not in self.material]
        if need:
            raise ValueError(f"{self.job_template.source} uses material constants {need}; give them in an isotropic "
                             "[model.material]")

    def apply_materials(self, materials: Mapping[str | None, Material], *, scene_file: str | Path | None = None,
                        mesh: str | Path | None = None) -> None:
        """Give every element the material of the named ``*ELSET`` it lies in, the default (key ``None``)
        when none (:func:`.sections.assign_sections`: SceneErrors naming the key). The shipped template is
        ``job.inp`` for one isotropic material on every element (its ``${E} ${nu} ${rho}``: the deck as it
        always was), else ``materials_job.inp`` (``${materials}``); a user's template needs ``${materials}``
        for regions or orthotropic constants."""
        if self.deck is not None:
            raise SceneError(scene_file, "model.materials", f"the deck {self.deck.path} carries its own *MATERIAL "
                             "blocks: remove [model.material] and [model.materials]")
        if self._K is not None:
            raise RuntimeError("apply_materials after K was built")
        ids = np.concatenate([e for _, e, _ in self.blocks])
        sections = assign_sections(ids, self.element_sets, materials, scene_file=scene_file, mesh=mesh)
        if not self.user_template:
            self.job_template = shipped_template("job.inp" if is_plain(sections) else "materials_job.inp")
        elif not is_plain(sections) and "materials" not in self.job_template.placeholders:
            asked = "[model.materials] regions" if len(sections) > 1 or sections[0].elements is not None else \
                "orthotropic constants"
            raise SceneError(scene_file, "model.template", f"the job template {self.job_template.source} has no "
                             f"${{materials}} placeholder, so it cannot hold the {asked} of the scene: put a line "
                             "${materials} where its *MATERIAL and *SOLID SECTION blocks stand (stepnf writes them "
                             "there), or give one isotropic [model.material] (its ${E}, ${nu}, ${rho})")
        self.sections = sections
        default = materials.get(None)
        self.material = ({k: float(default.constants[k]) for k in MATERIAL_KEYS}
                         if default is not None and default.isotropic else {})
        self._check_template()

    @property
    def n_full(self) -> int:
        """Number of nodal dofs, fixed ones included (3 per node)."""
        return 3 * len(self.node_ids)

    # ------------------------------------------------------------ builders
    @classmethod
    def from_volume_mesh(cls, mesh: Any, **kw: Any) -> "CalculixAdapter":
        """From a :class:`stepnf.geometry.VolumeMesh` (or anything with ``points``, ``cells``, ``cell_type``;
        its ``node_sets``, if any, name node positions: a generated cap's ``"edge"``)."""
        if mesh.cell_type not in CCX_ELEMENTS:
            raise ValueError(f"cell type {mesh.cell_type!r} has no CalculiX element here. Pick one of {list(CCX_ELEMENTS)}")
        ccx_type, perm = CCX_ELEMENTS[mesh.cell_type]
        ids = np.arange(1, len(mesh.points) + 1)
        conn = np.asarray(mesh.cells)[:, perm] + 1
        kw.setdefault("midsurface", getattr(mesh, "midsurface", None))
        kw.setdefault("node_sets", getattr(mesh, "node_sets", None))
        ad = cls(ids, mesh.points, [(ccx_type, np.arange(1, len(conn) + 1), conn)], **kw)
        if mesh.cell_type == "hexahedron20":
            ad.hex20_cells = np.asarray(mesh.cells, dtype=np.int64)
        return ad

    @classmethod
    def from_inp(cls, path: str | Path, **kw: Any) -> "CalculixAdapter":
        """A user's mesh from an ``.inp`` or Gmsh ``.msh`` file, with its named sets (see :mod:`.inpmesh`)."""
        from .inpmesh import read_mesh_file

        m = read_mesh_file(path)
        ad = cls(m.node_ids, m.points, m.blocks, node_sets=m.node_sets, element_sets=m.element_sets, source=path,
                 **kw)
        ad.facets_ignored = dict(m.facets)
        return ad

    from_mesh_file = from_inp  # the ``mesh`` key (SolidFromScene)

    @classmethod
    def from_deck(cls, path: str | Path, **kw: Any) -> "CalculixAdapter":
        """A user's whole CalculiX deck (see :mod:`.userdeck`): its model data, materials and zero
        ``*BOUNDARY`` conditions; its steps are replaced by stepnf's."""
        from .userdeck import read_deck

        d = read_deck(path)
        return cls(d.mesh.node_ids, d.mesh.points, d.mesh.blocks, node_sets=d.mesh.node_sets, deck=d, **kw)

    from_deck_file = from_deck  # the ``deck`` key (SolidFromScene)

    @classmethod
    def validate_config(cls, config: Mapping[str, Any], *, base_dir: str | Path,
                        scene_file: str | Path | None = None) -> dict[str, Any]:
        """The ``[model]`` keys (:func:`stepnf.external.check_solid_config`); a deck takes no job template; a
        relative ``executable`` (allowed by the user: :mod:`stepnf.runtime.programs`) is made absolute from ``base_dir``."""
        c = super().validate_config(config, base_dir=base_dir, scene_file=scene_file)
        if "executable" in c:  # a relative path is the scene's, not the current folder's
            c["executable"] = resolve_program(c["executable"], base_dir)
        if "deck" in c and "template" in c:
            raise SceneError(scene_file, "model.template", f"the deck {c['deck']} is the model: stepnf includes it "
                             "and appends its own steps, so no job template is used; remove template")
        return c

    @classmethod
    def input_files(cls, checked: Mapping[str, Any]) -> list[Path]:
        """The files a ``deck`` or ``mesh`` includes (``*INCLUDE``, nested ones too), for the key of stored
        results (:mod:`stepnf.scene.model_key`); an unreadable deck is left to the build to report."""
        from stepnf.geometry.inp import inp_lines

        out: list[Path] = []
        for key in ("deck", "mesh"):
            if checked.get(key) is not None:
                try:
                    out += [p for p in dict.fromkeys(line.source.path for line in inp_lines(Path(checked[key])))
                            if p != Path(checked[key])]
                except (OSError, SceneError):
                    pass
        return out

    def output_mesh(self):
        """The nodes and elements ccx runs, for the ParaView fields (:mod:`.fields_mesh`)."""
        from .fields_mesh import deck_output_mesh

        return deck_output_mesh(self.node_ids, self.points, self.blocks)

    def summary(self) -> str:
        """The run's first line about the model: ``mesh: 40 C3D20 elements (order 2), 729 nodes, 2 187 dofs``
        (and the facet elements of the mesh file left out, :mod:`.inpmesh`)."""
        elements = ", ".join(f"{thousands(len(e))} {t}" for t, e, _ in self.blocks)
        orders = sorted({1 if t in LINEAR_TYPES else 2 for t, _, _ in self.blocks})
        free = " free" if self.free_dofs is not None else ""
        facets = "; not modelled: " + ", ".join(f"{n} {t} facets" for t, n in self.facets_ignored.items()) \
            if self.facets_ignored else ""
        return (f"mesh: {elements} elements (order {' and '.join(map(str, orders))}), {thousands(len(self.node_ids))} "
                f"nodes, {thousands(self.n_dofs)}{free} dofs{facets}")

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d.update(
            solver="CalculiX", executable=self.executable, n_nodes=int(len(self.node_ids)),
            elements={t: int(len(e)) for t, e, _ in self.blocks}, template=self.job_template.source,
            material=self.material, geometry={k: (str(v) if isinstance(v, float) and math.isinf(v) else v)
                                              for k, v in self.geometry.items()},
            force_precision=f"{self.force_digits} significant digits (.dat)", solver_runs=len(self.runs),
        )
        if self.sections is not None and not is_plain(self.sections):
            d["materials"] = [s.describe() for s in self.sections]
        if self.deck is not None:
            d["deck"] = self.deck.summary
        if self.facets_ignored:
            d["facets_ignored"] = dict(self.facets_ignored)
        if self.free_dofs is not None:
            d["boundary"] = {"conditions": list(self.applied_conditions), **self.free_dofs.describe(),
                             "from_deck": int(len(self.deck.fixed)) if self.deck is not None else 0}
        return d

    # ---------------------------------------------------------------- jobs
    def run_env(self) -> dict[str, str]:
        return {} if self.threads is None else {"OMP_NUM_THREADS": str(int(self.threads))}

    def _write_job(self, workdir: Path, job: str, steps: str, title: str) -> list[str]:
        (workdir / "mesh.inp").write_text(self._mesh)
        values = {"title": title, "mesh_file": "mesh.inp", "steps": steps}
        if self.sections is not None:
            values["materials"] = materials_text(self.sections)
        values.update({k: REAL % float(v) for k, v in self.material.items() if k in MATERIAL_KEYS})
        (workdir / f"{job}.inp").write_text(self.job_template.render(values))
        return [self.executable, "-i", job]

    def write_force_job(self, workdir: Path, U: np.ndarray) -> list[str]:
        steps = "\n".join(
            self.step_template.render(index=i + 1, nset=self.nset,
                                      boundary=format_boundary(self.node_ids, self.nodal(u)))
            for i, u in enumerate(U)
        )
        return self._write_job(workdir, "forces", steps, f"internal forces of {len(U)} prescribed fields")

    def read_forces(self, workdir: Path, m: int) -> np.ndarray:
        (dat,) = require_files(workdir, ["forces.dat"], log=workdir / "solver.log", what="ccx")
        try:
            F = read_dat_forces(dat, self.node_ids, m)
        except ResultFormatError as exc:
            raise missing_output(workdir, f"ccx output incomplete: {exc}") from None
        return self.free_part(F.reshape(m, -1))

    def _matrices(self) -> None:
        """One matrix run (LazyMatrices calls it once, and times it as ``timings["matrices"]``)."""
        with self.work_folder(prefix="calculix-matrices-") as wd:
            argv = self._write_job(wd, "matrices", self.matrix_template.render(), "K and M (matrix storage)")
            rec = self.run(argv, wd)
            K, M = self._read_stored_matrices(wd, "matrices", rec.log)
            self._K, self._M = self.free_part(K), self.free_part(M)

    def _read_stored_matrices(self, wd: Path, job: str, log: Path) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        """K and M of a ``SOLVER=MATRIXSTORAGE`` run, over every nodal dof in this adapter's order.

        Garbage, truncation or NaN in the ``.dof``/``.sti``/``.mas`` files is a
        :class:`~stepnf.errors.SolverRunError` naming the file, the work folder and the log's end.
        """
        sti, mas, dof = require_files(wd, [f"{job}.sti", f"{job}.mas", f"{job}.dof"], log=log, what="ccx")
        try:
            nodes, dirs = read_dof(dof)
        except ResultFormatError as exc:
            raise missing_output(wd, f"ccx output unreadable: {exc}") from None
        n = self.n_full
        ok = (nodes >= 0) & (nodes <= self._pos.size - 1) & (dirs >= 1) & (dirs <= 3)
        index = np.where(ok, self._pos[np.clip(nodes, 0, self._pos.size - 1)] * 3 + dirs - 1, -1)
        if len(index) != n or np.any(index < 0) or len(np.unique(index)) != n:
            raise missing_output(
                wd, f"{job}.dof lists {len(index)} dofs, expected the {n} = 3 x {n // 3} nodal translations"
            )
        try:
            K, M = read_matrix(sti, n), read_matrix(mas, n)
        except ResultFormatError as exc:
            raise missing_output(wd, f"ccx output unreadable: {exc}") from None
        return _permute(K, index), _permute(M, index)

    # -------------------------------------------------- tangent stiffness
    def tangent_stiffness(self, u: np.ndarray) -> sp.csr_matrix:
        """Tangent stiffness ``df/du`` at the displacement ``u`` (n,), 14 digits (one ccx run).

        An NLGEOM step prescribes ``u`` (the fixed dofs at 0); a ``*STEP, PERTURBATION``
        then stores the tangent at that state, whose free rows and columns are kept. For
        the exact cubic f of this model, ``K_T(u) = K + 2 G(u, .) + 3 H(u, u, .)``.
        """
        u = self._check_field(u)
        tpl = shipped_template("tangent_step.inp")
        with self.work_folder(prefix="calculix-tangent-") as wd:
            steps = tpl.render(boundary=format_boundary(self.node_ids, self.nodal(u)))
            argv = self._write_job(wd, "tangent", steps, "tangent stiffness at a prescribed field")
            rec = self.run(argv, wd)
            KT, _ = self._read_stored_matrices(wd, "tangent", rec.log)
        return self.free_part(KT)

    def sharp_step(self, phi: np.ndarray, q: float) -> tuple[np.ndarray, float]:
        """``G(phi, phi)`` (n,) and ``phi . H(phi, phi, phi)`` from the tangents at ``+-q phi`` (two ccx runs).

        ``K_T(q phi) - K_T(-q phi) = 4 q G(phi, .)`` and
        ``K_T(q phi) + K_T(-q phi) - 2 K = 6 q^2 H(phi, phi, .)`` hold exactly
        for a cubic f, and the tangents carry 14 digits where the printed
        forces carry 7: use this to sharpen STEP's cubic terms.
        """
        phi = self._check_field(phi)
        Kp, Km = self.tangent_stiffness(q * phi), self.tangent_stiffness(-q * phi)
        Gv = (Kp - Km) @ phi / (4.0 * q)
        h = float(phi @ ((Kp + Km - 2.0 * self.stiffness_matrix()) @ phi)) / (6.0 * q * q)
        return Gv, h


def _permute(A: sp.csr_matrix, index: np.ndarray) -> sp.csr_matrix:
    """Row/column ``r`` of ``A`` becomes row/column ``index[r]``."""
    C = A.tocoo()
    return sp.csr_matrix((C.data, (index[C.row], index[C.col])), shape=A.shape)
