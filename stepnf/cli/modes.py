"""``stepnf modes SCENE``: which mode is which, from one eigen-solve, before paying for STEP.

:func:`modal_survey` builds the scene's model, computes its first elastic modes
(the same matrices, rigid-body search, eigen-solver and orientation of
degenerate pairs as ``stepnf run``) and returns a :class:`ModeSurvey`: per mode
its index (0-based among the elastic modes, as ``master_modes`` counts), the
angular frequency, w_bar for a shell, the adapter's label, and the share of
kinetic energy carried by each dof direction (``sum_{i in d} phi_i (M phi)_i``,
which sums to 1 for an M-normalised mode shape).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stepnf.plugin.adapter import DIRECTIONS
from stepnf.errors import SceneError
from stepnf.linalg.modal_analysis import degenerate_groups, modal_analysis, orient_degenerate, probe_vector
from stepnf.plugin.modal_model import ModalModel
from stepnf.pipeline.model import model_stage, open_model
from stepnf.pipeline.outputs import RunContext
from stepnf.pipeline.plan import check_elastic_modes, check_mechanism, resolve_masters
from stepnf.runtime.progress import Progress
from stepnf.io.results import label_json, label_text
from stepnf.scene.parse import Scene

DEFAULT_MODES = 12


@dataclass
class ModeSurvey:
    """The first elastic modes of a scene's model."""

    solver: str
    omega: np.ndarray
    labels: list[Any]
    omega_bar: list[float] | None = None
    energy: dict[str, np.ndarray] | None = None  # direction name -> share of each mode (None: no directions)
    degenerate_groups: list[list[int]] = field(default_factory=list)
    n_rigid: int = 0
    n_dofs: int | None = None
    eigensolver: str = ""
    masters: list[int] = field(default_factory=list)  # the scene's master modes among those listed
    masters_note: str | None = None  # why the scene's master modes could not all be placed
    mechanism: str | None = None  # boundary conditions leaving rigid-body modes: what `stepnf run` refuses, and why
    massless: int = 0  # directions without mass (a singular M) left out of a dense eigen-solve

    @property
    def n_modes(self) -> int:
        return len(self.omega)

    @property
    def has_labels(self) -> bool:
        return any(x is not None for x in self.labels)

    def to_dict(self) -> dict[str, Any]:
        modes = []
        for i, w in enumerate(self.omega):
            rec: dict[str, Any] = {"index": i, "omega": float(w), "label": label_json(self.labels[i])}
            if self.omega_bar is not None:
                rec["omega_bar"] = float(self.omega_bar[i])
            rec["energy"] = ({d: float(s[i]) for d, s in self.energy.items()}
                             if self.energy is not None else None)
            rec["degenerate_with"] = [j for g in self.degenerate_groups if i in g for j in g if j != i]
            rec["master"] = i in self.masters
            modes.append(rec)
        return {"solver": self.solver, "n_dofs": self.n_dofs, "n_rigid": self.n_rigid,
                "eigensolver": self.eigensolver, "labels": self.has_labels,
                "degenerate_groups": self.degenerate_groups, "masters": self.masters,
                "masters_note": self.masters_note, "mechanism": self.mechanism, "massless": self.massless,
                "modes": modes}

    def to_json(self, **kw: Any) -> str:
        return json.dumps(self.to_dict(), allow_nan=False, **kw)


def _too_many(scene: Scene, n: int, available: int, why: str) -> SceneError:
    return SceneError(scene.file, None, f"-n {n}: {why} has only {available} elastic modes; "
                      f"allowed 1..{available}")


def modal_survey(scene: Scene, n: int | None = None, progress: Progress | None = None) -> ModeSurvey:
    """The first ``n`` elastic modes of ``scene``'s model.

    Without ``n``: :data:`DEFAULT_MODES`, or more until the scene's master
    modes (indices or labels) are all among them, as ``stepnf run`` would
    find them; they are marked in the listing. A master the model does not
    have is said in ``masters_note``, not raised: the listing is how to find
    the right one.

    An ``n`` beyond the model's dofs minus its rigid-body modes is a :class:`SceneError` (exit 2),
    refused before the eigen-solve when the count is known then.
    """
    progress = progress or Progress(enabled=False)
    if n is not None and n < 1:
        raise SceneError(scene.file, None, f"-n {n}: expected a positive number of modes")
    model = open_model(scene, progress)
    try:
        if isinstance(model, ModalModel):
            return _modal_model_survey(scene, model, n)
        return _adapter_survey(scene, model, n, progress)
    finally:
        model.close()


def _placed_masters(scene: Scene, labels: list[Any], n_modes: int, complete: bool
                    ) -> tuple[list[int] | None, str | None]:
    """The scene's master modes among ``n_modes``: (indices, None); (None, None) while more modes are
    needed (``complete=False``); ([], why) when they cannot be placed (the survey says why, it does not stop)."""
    try:
        return resolve_masters(scene, labels, n_modes, complete=complete), None
    except SceneError as exc:
        where = f"[{exc.key}]: " if exc.key else ""
        return [], where + exc.message


def _listed(n: int | None, masters: list[int], available: int) -> int:
    """How many modes to list: ``n``, else the default or up to the highest master."""
    if n is not None:
        return min(n, available)
    return min(max(DEFAULT_MODES, max(masters, default=-1) + 1), available)


def _modal_model_survey(scene: Scene, model: ModalModel, n: int | None) -> ModeSurvey:
    omega = np.asarray(model.omegas(), dtype=float)
    m = len(omega)
    if n is not None and n > m:
        raise _too_many(scene, n, m, f"the {scene.solver} model")
    all_labels = list(model.labels())
    masters, note = _placed_masters(scene, all_labels, m, complete=True)
    k = _listed(n, masters or [], m)
    labels = all_labels[:k]
    scales = model.shell_scales()
    groups = [g for g in degenerate_groups(omega, scene.degeneracy_tolerance) if min(g) < k]
    return ModeSurvey(solver=scene.solver, omega=omega[:k], labels=labels,
                      omega_bar=[scales.omega_bar(w) for w in omega[:k]] if scales is not None else None,
                      degenerate_groups=groups, eigensolver="modal model",
                      masters=[i for i in masters or [] if i < k], masters_note=note)


def _adapter_survey(scene: Scene, adapter: Any, n: int | None, progress: Progress) -> ModeSurvey:
    # the model stage of a run (stepnf.pipeline.model): the same matrices, checks and rigid-body fields
    model = model_stage(RunContext.start(scene, progress), adapter, survey=True)
    K, M, X, dirs, ndof = model.K, model.M, model.X, model.dirs, model.n
    known_rigid = scene.rigid_modes or 0
    if n is not None and n > ndof - known_rigid:
        raise _too_many(scene, n, ndof - known_rigid,
                        f"the model ({ndof} dofs, {known_rigid} rigid-body modes)" if known_rigid
                        else f"the model ({ndof} dofs)")
    k = n or DEFAULT_MODES
    eig = adapter.eigenmodes if adapter.provides_eigenmodes else None

    def enough(b: Any) -> bool:  # without -n: on until the scene's master modes are all found
        if n is not None:
            return True
        return _placed_masters(scene, list(adapter.mode_labels(b.phi)), b.n_elastic, complete=False)[0] is not None

    with progress.stage("eigen", "modal analysis"):
        basis = modal_analysis(K, M, k, rigid_tolerance=scene.rigid_tolerance, rigid_modes=scene.rigid_modes,
                               degeneracy_tolerance=scene.degeneracy_tolerance,
                               max_modes=max(scene.max_modes, k + 8),
                               backend=model.backend, enough=enough,
                               eigensolver=eig, rigid_candidates=model.candidates, progress=progress.message)
    check_elastic_modes(scene, basis)
    n_rigid = int(basis.rigid.shape[1])
    try:  # the survey says what `stepnf run` would refuse, and lists the modes anyway
        check_mechanism(scene, adapter, basis)
        mechanism = None
    except SceneError as exc:
        mechanism = f"[{exc.key}]: {exc.message}"
    if n is not None and basis.n_elastic < n:
        raise _too_many(scene, n, basis.n_elastic, f"the model ({ndof} dofs, {n_rigid} rigid-body modes)")
    orient_degenerate(basis, M, probe_vector(X, dirs, ndof))
    all_labels = list(adapter.mode_labels(basis.phi))
    masters, note = _placed_masters(scene, all_labels, basis.n_elastic, complete=True)
    k = _listed(n, masters or [], basis.n_elastic)
    phi = basis.phi[:, :k]
    labels = all_labels[:k]
    scales = adapter.shell_scales()
    omega = basis.omega[:k]
    return ModeSurvey(solver=scene.solver, omega=omega, labels=labels,
                      omega_bar=[scales.omega_bar(w) for w in omega] if scales is not None else None,
                      energy=kinetic_shares(phi, M, dirs), n_rigid=n_rigid, n_dofs=ndof,
                      degenerate_groups=[g for g in basis.degenerate_groups if min(g) < k],
                      eigensolver=basis.solver, masters=[i for i in masters or [] if i < k], masters_note=note,
                      mechanism=mechanism, massless=basis.massless)


def kinetic_shares(phi: np.ndarray, M: Any, dirs: np.ndarray | None) -> dict[str, np.ndarray] | None:
    """Share of each mode's kinetic energy per dof direction: ``sum_{i in d} phi_i (M phi)_i``.

    Columns of ``phi`` M-normalised: the shares of a mode sum to 1. ``None`` without directions.
    """
    if dirs is None:
        return None
    dirs = np.asarray(dirs)
    terms = phi * np.asarray(M @ phi)
    return {DIRECTIONS[d]: terms[dirs == d].sum(axis=0) for d in sorted({int(x) for x in dirs})}


def format_survey(s: ModeSurvey) -> str:
    """The human-readable listing of ``stepnf modes``."""
    dirs = list(s.energy) if s.energy is not None else []
    cols = ["mode", "label", "omega"] + (["w_bar"] if s.omega_bar is not None else []) + dirs + ["degenerate"]
    cols.append("master")
    rows = []
    for i, w in enumerate(s.omega):
        row = [str(i), label_text(s.labels[i]), f"{w:.6g}"]
        if s.omega_bar is not None:
            row.append(f"{s.omega_bar[i]:.4f}")
        row += [f"{s.energy[d][i]:.3f}" for d in dirs] if s.energy is not None else []
        twins = [j for g in s.degenerate_groups if i in g for j in g if j != i]
        row.append(",".join(str(j) for j in twins) or "-")
        row.append("*" if i in s.masters else "")
        rows.append(row)
    widths = [max(len(c), *(len(r[j]) for r in rows)) if rows else len(c) for j, c in enumerate(cols)]
    dofs = f", {s.n_dofs} dofs" if s.n_dofs is not None else ""
    lines = [f"stepnf modes: {s.solver}{dofs}, first {s.n_modes} elastic modes ({s.eigensolver})",
             "  ".join(c.ljust(w) for c, w in zip(cols, widths)), "  ".join("-" * w for w in widths)]
    lines += ["  ".join(v.ljust(w) for v, w in zip(r, widths)).rstrip() for r in rows]
    lines.append(f"rigid-body modes found: {s.n_rigid}" + (" (null vectors of K, set aside before mode 0: [analysis] "
                 "rigid_modes = \"auto\"; an integer rigid_modes fixes the count)" if s.n_rigid else ""))
    if s.mechanism:
        lines.append(f"mechanism: {s.mechanism}")
    if s.massless:
        lines.append(f"massless: M is singular: {s.massless} directions without mass (infinite eigenvalues) left out")
    if s.energy is not None:
        lines.append("columns " + ", ".join(dirs) + ": share of the mode's kinetic energy in that direction")
    else:
        what = "a modal model has no dofs" if s.n_dofs is None else "the solver gives no dof directions"
        lines.append(f"kinetic-energy shares: - ({what})")
    if not s.has_labels:
        lines.append(f"labels: - (the {s.solver} solver gives no mode labels)")
    if s.masters:
        lines.append("master: * marks the scene's master modes")
    if s.masters_note:
        lines.append(f"master modes: {s.masters_note}")
    for g in s.degenerate_groups:
        lines.append(f"degenerate: modes {', '.join(str(j) for j in g)} (equal frequencies; "
                     "any combination is a mode)")
    return "\n".join(lines)
