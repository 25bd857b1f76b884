"""The evaluation plan: which evaluator serves each requested method, which modes are the masters."""
from __future__ import annotations

from typing import Any, Sequence

from stepnf.errors import NumericalError, SceneError
from stepnf.io.results import label_text
from stepnf.linalg.modal_analysis import ModalBasis
from stepnf.linalg.null_space import moving_dofs
from stepnf.methods import evaluators
from stepnf.scene.parse import Scene, parse_label


def resolve_methods(methods: Sequence[str], qm_order: str) -> dict[str, str]:
    """Map each requested name to its evaluator: ``md``/``smd`` follow ``qm_order``
    (:meth:`stepnf.methods.Method.resolve`)."""
    return evaluators(methods, qm_order)


def _label_matches(label: Any, want: Any) -> bool:
    if label is None:
        return False
    if isinstance(want, tuple) and isinstance(label, (tuple, list)):
        return tuple(int(x) for x in label[:2]) == want
    return str(label) == str(want)


def resolve_masters(scene: Scene, labels: Sequence[Any], n_modes: int, *, complete: bool) -> list[int] | None:
    """Elastic-mode indices of the scene's master modes; None when more modes are needed.

    Raises :class:`SceneError` when a label or index cannot exist.
    """
    out = []
    for i, m in enumerate(scene.master_modes):
        if isinstance(m, int):
            if m >= n_modes:
                if complete:
                    raise SceneError(scene.file, f"analysis.master_modes[{i}]",
                                     f"mode {m} does not exist: the model has {n_modes} elastic modes (0..{n_modes - 1})")
                return None
            out.append(m)
            continue
        want = parse_label(m) or m
        hits = [s for s, lab in enumerate(labels) if _label_matches(lab, want)]
        if not hits:
            if complete and not any(x is not None for x in labels):
                raise SceneError(scene.file, f"analysis.master_modes[{i}]",
                                 f"{m!r} is a mode label, but the {scene.solver} model gives no labels ((k, n) "
                                 "labels exist for axisymmetric structures: generated caps, a mesh with "
                                 "model.geometry a, R, h, the von Karman model); give a 0-based mode index "
                                 "(`stepnf modes` lists them)")
            if complete:
                found = sorted({label_text(x) for x in labels if x is not None},
                               key=lambda t: (len(t), t))
                more = f" and {len(found) - 30} more" if len(found) > 30 else ""
                raise SceneError(scene.file, f"analysis.master_modes[{i}]",
                                 f"no mode is labelled {m!r} among the {n_modes} modes computed; "
                                 f"labels found: {found[:30]}{more}")
            return None
        out.append(hits[0])
    if len(set(out)) != len(out):
        raise SceneError(scene.file, "analysis.master_modes", f"two entries name the same mode: {out}")
    return out


def check_rigid_count(scene: Scene, n: int) -> None:
    """``analysis.rigid_modes`` must leave elastic modes: at most ``n - 1`` of the model's ``n`` dofs."""
    if scene.rigid_modes is not None and scene.rigid_modes >= n:
        raise SceneError(scene.file, "analysis.rigid_modes",
                         f"{scene.rigid_modes} rigid-body modes asked for, but the model has only {n} dofs: "
                         f"allowed 0..{n - 1} (or \"auto\")")


def check_elastic_modes(scene: Scene, basis: ModalBasis) -> None:
    """A model with no elastic mode (K zero, or every mode counted rigid) is refused, naming why."""
    if basis.n_elastic or not basis.rigid.shape[1]:
        return
    if scene.rigid_modes is not None:
        raise SceneError(scene.file, "analysis.rigid_modes",
                         f"rigid_modes = {scene.rigid_modes} leaves no elastic mode among the "
                         f"{basis.rigid.shape[1]} computed; allowed: fewer rigid modes, or \"auto\"")
    raise NumericalError(f"the model has no elastic mode: all {basis.rigid.shape[1]} computed modes have "
                         f"|w^2| <= analysis.rigid_tolerance ({scene.rigid_tolerance:g}) x lambda_max, so the "
                         "stiffness matrix K is zero or nearly so for the solver's model ([model] of "
                         f"{scene.where()}); check K, the material's Young's modulus and the units")


def check_mechanism(scene: Scene, adapter: Any, basis: ModalBasis) -> None:
    """Boundary conditions that still leave rigid-body modes (null vectors of K) are refused (exit 2), naming
    their count and the dofs they move, unless ``analysis.rigid_modes`` accepts them: conditions meant to
    hold a structure leave none."""
    from stepnf.plugin.boundary import check_mechanism as why

    if scene.rigid_modes is not None or adapter.free_dof_map() is None:
        return
    r = int(basis.rigid.shape[1])
    reason = why(r, True)
    if reason is not None:
        X, D = adapter.dof_coordinates(), adapter.dof_directions()
        moves = "; ".join(f"mode {j}: {moving_dofs(basis.rigid[:, j], X, D)}" for j in range(min(r, 3)))
        # the conditions are the scene's [[model.boundary]], else a deck's own *BOUNDARY
        key = "model.deck" if scene.model.get("deck") and not scene.model.get("boundary") else "model.boundary"
        raise SceneError(scene.file, key, f"{reason} ({moves}{'; ...' if r > 3 else ''})")
