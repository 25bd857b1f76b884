"""Run a scene: adapter -> modal analysis -> evaluation plan -> STEP -> evaluators -> results.

Only what the scene asks for is computed: NF/DNF/MD/SMD of one master mode
need the targeted STEP (two force evaluations, four with the amplitude check),
whatever the model size; the full STEP over the retained modes runs only when
``analysis.tensors = "full"``.
"""
from __future__ import annotations

import time
from dataclasses import asdict, replace
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from .adapter import SolverAdapter
from .backbone import MethodResult
from .checkpoint import Checkpoint
from .counters import Counters
from .deflation import DeflatedSolver
from .errors import SceneError
from .evaluators import (FullOrderContext, Tolerances, _resonance_flags, coupled, dnf, md_full, md_modal,
                         nf_modal, retained_set, smd_full, smd_modal)
from .linalg import Factorization, PseudoInverse, _apply_cols, choose_backend
from .modal import ModalBasis, modal_analysis, rigid_body_fields
from .modal_model import ModalModel
from .progress import Progress
from .registry import get_solver
from .results import ModeResult, RunResult, label_text, write_hdf5
from .scene import Scene, parse_label
from .step import ForceEvaluator, full_step, step_amplitude, targeted_steps, targeted_steps_tangent

MODAL_METHODS = {"nf", "md_modal", "smd_modal"}
FULL_METHODS = {"dnf", "md_full", "smd_full"}


def resolve_methods(methods: Sequence[str], qm_order: str) -> dict[str, str]:
    """Map each requested name to its evaluator: ``md``/``smd`` follow ``qm_order``."""
    out = {}
    for m in methods:
        if m in ("md", "smd"):
            out[m] = f"{m}_{qm_order}"
        else:
            out[m] = m
    return out


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
            if complete:
                found = sorted({label_text(x) for x in labels if x is not None})
                raise SceneError(scene.file, f"analysis.master_modes[{i}]",
                                 f"no mode is labelled {m!r} among the {n_modes} modes computed; "
                                 f"labels found: {found}")
            return None
        out.append(hits[0])
    if len(set(out)) != len(out):
        raise SceneError(scene.file, "analysis.master_modes", f"two entries name the same mode: {out}")
    return out


def slow_fast_ratio(p: int, omega: np.ndarray, g: np.ndarray, tol: Tolerances,
                    twins: Sequence[int], floor: np.ndarray | float | None = None) -> tuple[float | None, int | None]:
    """rho_p = min over coupled slave modes s of w_s / w_p (paper Eq. 8).

    Slaves are the modes that the master drives through ``g^s_pp`` (others
    cannot break the slow/fast assumption); when none couples, every
    non-twin slave counts, as in the paper's literal definition.
    """
    cp = coupled(g, tol.coupling, floor)
    cand = [s for s in range(len(omega)) if s != p and cp[s]]
    if not cand:
        cand = [s for s in range(len(omega)) if s != p and s not in twins]
    if not cand:
        return None, None
    r = omega[cand] / omega[p]
    j = int(np.argmin(r))
    return float(r[j]), int(cand[j])


def floor_scale(st, M: sp.spmatrix, tol: Tolerances) -> float:
    """``tol.coupling * ||G(phi_p, phi_p)||`` in the lumped ``M^-1`` norm (bounds every ``|g^s_pp|``)."""
    dm = np.asarray(M.diagonal()).ravel()
    return tol.coupling * float(np.sqrt(np.sum(st.Gv**2 / np.where(dm > 0, dm, np.inf))))


def _one_two_flags(p: int, w: float, st, basis: ModalBasis, ctx: FullOrderContext, floor0: float,
                   tol: Tolerances, adapter: SolverAdapter, counters: Counters) -> list[dict]:
    """DNF's 1:2 check: the modes nearest ``2 w_p``, found with the DNF's own ``K - 4 w^2 M`` factors."""
    top = basis.omega[-1] if basis.n_elastic else 0.0
    if basis.complete or top >= 2.0 * w * (1 + tol.resonance):
        near_w, near_phi = basis.omega, basis.phi  # every mode near 2 w_p is among the computed ones
    else:
        near_w, near_phi = _ritz_near(ctx, 4 * w * w, st.Gv, counters)
    g = near_phi.T @ st.Gv
    floor = np.full(len(g), floor0)
    if st.Gv_check is not None:
        floor = np.maximum(floor, 10.0 * np.abs(near_phi.T @ (st.Gv - st.Gv_check)))
    labels = adapter.mode_labels(near_phi) if not basis.complete else list(adapter.mode_labels(near_phi))
    flags = []
    for j in np.nonzero(coupled(g, tol.coupling, floor))[0]:
        r = near_w[j] / w
        if abs(r - 2.0) > 2.0 * tol.resonance:
            continue
        hit = np.nonzero(np.isclose(basis.omega, near_w[j], rtol=1e-9))[0]
        s_idx = int(hit[0]) if len(hit) else None
        name = (f"mode {s_idx}" if s_idx is not None else f"a mode at w = {near_w[j]:.6g}") + \
            (f" {labels[j]}" if labels[j] is not None else "")
        flags.append({"kind": "internal_resonance_1_2", "mode": s_idx, "label": labels[j], "ratio": float(r),
                      "omega": float(near_w[j]),
                      "message": f"DNF: {name} is in 1:2 internal resonance with master mode {p} "
                                 f"(w_s/w_p = {r:.4f}); the normal form has a small denominator there"})
    return flags


def _ritz_near(ctx: FullOrderContext, sigma: float, Gv: np.ndarray, counters: Counters,
               steps: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Rayleigh-Ritz on ``span{Z^-1 Gv, (Z^-1 M)^2 Gv, ...}``, ``Z = K - sigma M`` (DNF's factors).

    Inverse iteration from ``G(phi_p, phi_p)`` amplifies exactly the modes that
    are both coupled to the master and near ``sqrt(sigma) = 2 w_p``, so three
    solves find the modes a 1:2 resonance could come from.
    """
    Z = ctx.shifted_factorization(sigma, "")
    R = ctx.Kpinv.R
    v = Gv - ctx.M @ (R @ (R.T @ Gv)) if R.shape[1] else Gv
    V = []
    for _ in range(steps):
        v = Z.solve(v, count=False)
        counters.eigensolver_solves += 1
        V.append(v)
        v = ctx.M @ v
    V = np.column_stack(V)
    Mr = V.T @ (ctx.M @ V)
    Kr = V.T @ (ctx.K @ V)
    d = np.sqrt(np.abs(np.diag(Mr)))
    Mr, Kr, V = Mr / np.outer(d, d), Kr / np.outer(d, d), V / d
    lam, y = np.linalg.eigh(Mr)
    keep = lam > 1e-12 * lam.max()  # drop directions the iteration made dependent
    T = y[:, keep] / np.sqrt(lam[keep])
    mu, z = np.linalg.eigh(T.T @ Kr @ T)
    phi = V @ (T @ z)
    return np.sqrt(np.maximum(mu, 0.0)), phi


def _adapter_shifted(shift_solver, n: int, counters: Counters):
    """The adapter's own ``K - sigma M`` factorisations, as :class:`Factorization` objects."""
    def shifted(sigma: float, label: str) -> Factorization:
        counters.factorizations += 1
        raw = shift_solver(sigma)
        return Factorization(lambda b: _apply_cols(raw, b), n, "adapter", counters, label)
    return shifted


class _DeflatedPinv:
    """``K^+`` through a :class:`DeflatedSolver` (same interface as :class:`PseudoInverse`)."""

    def __init__(self, solver: DeflatedSolver, R: np.ndarray):
        self.solver, self.R = solver, R

    def __call__(self, b: np.ndarray) -> np.ndarray:
        return self.solver.pinv(b)


def coupling_floor(st, Phi: np.ndarray, M: sp.spmatrix, tol: Tolerances) -> np.ndarray:
    """Per-mode threshold under which ``g^s_pp`` counts as zero (uncoupled by symmetry).

    ``tol.coupling`` times ``||G(phi_p, phi_p)||`` in the (lumped) ``M^-1``
    norm, which bounds every ``|g^s_pp|`` of M-normalised modes, and at least
    ten times the change of ``g^s_pp`` between the two STEP amplitudes (the
    noise the solver's forces carry).
    """
    floor = np.full(Phi.shape[1], floor_scale(st, M, tol))
    if st.Gv_check is not None:
        floor = np.maximum(floor, 10.0 * np.abs(Phi.T @ (st.Gv - st.Gv_check)))
    return floor


def captured_fraction(Gv: np.ndarray, g_retained: np.ndarray, M: sp.spmatrix) -> float:
    """Share of ``G(phi_p, phi_p)`` the retained modes carry: ``sum_S g_s^2 / (Gv^T M^-1 Gv)``.

    The modal sums of NF, MD and SMD see only that share; the rest lies on
    modes not retained (in-plane and thickness modes of a 3D solid). M^-1 by
    Jacobi-preconditioned CG (M is well conditioned).
    """
    import scipy.sparse.linalg as spla

    total2 = float(Gv @ Gv)
    if total2 == 0.0:
        return 1.0
    d = np.asarray(M.diagonal()).ravel()
    x, info = spla.cg(M, Gv, M=sp.diags(1.0 / d), tol=1e-10, atol=0.0, maxiter=500)
    full = float(Gv @ x)
    return float(np.sum(g_retained**2) / full) if full > 0 else 1.0


def truncation_flags(r: MethodResult, Gv: np.ndarray, g_retained: np.ndarray, M: sp.spmatrix,
                     n: int, threshold: float = 0.99) -> list[dict]:
    """Flag a modal-sum result whose retained modes miss more than 1% of the quadratic force."""
    frac = captured_fraction(Gv, g_retained, M)
    r.extra["captured_fraction"] = frac
    if frac >= threshold:
        return []
    return [{"kind": "modal_truncation", "value": frac,
             "message": f"{r.method.upper()}: the {n} retained modes carry only {100 * frac:.3g}% of "
                        "G(phi_p, phi_p) (M^-1 norm); the rest lies on modes not retained (in-plane and "
                        "thickness modes of a 3D model). Use dnf, or md/smd with qm_order = \"full\"."}]


def _t_error(T: float, T2: float) -> float:
    if not (np.isfinite(T) and np.isfinite(T2)):
        return 0.0 if T == T2 else float("inf")
    return abs(T - T2) / abs(T) if T != 0 else (0.0 if T2 == 0 else float("inf"))


def _modal_method(name: str, p: int, omega, g, h, S, tol, labels, floor=None) -> MethodResult:
    if name == "nf":
        return nf_modal(p, omega, g, h, S, tol=tol, labels=labels, floor=floor)
    if name == "md_modal":
        return md_modal(p, omega, g, h, S, tol=tol, labels=labels, floor=floor)
    if name == "smd_modal":
        return smd_modal(p, omega, g, h, S, tol=tol, labels=labels, floor=floor)
    raise KeyError(name)


def run_scene(scene: Scene, *, progress: Progress | None = None, write: bool = True) -> RunResult:
    """Compute what ``scene`` asks for and return (and, with ``write``, store) the results."""
    progress = progress or Progress(enabled=False)
    cls = get_solver(scene.solver)
    checkpoint = None
    t_start = time.perf_counter()
    if issubclass(cls, ModalModel):
        with progress.stage("model", f"building the {scene.solver} model"):
            model = cls.from_config(scene.model, base_dir=scene.base_dir, scene_file=scene.file)
        try:
            result = _run_modal_model(scene, model, progress)
        finally:
            model.close()
    else:
        with progress.stage("model", f"setting up the {scene.solver} model"):
            adapter = cls.from_config(scene.model, base_dir=scene.base_dir, scene_file=scene.file)
        if write and scene.write_hdf5:
            checkpoint = Checkpoint(scene.output_dir / f".{scene.output_name}.partial")
        try:
            result = _run_adapter(scene, adapter, progress, checkpoint)
        finally:
            adapter.close()
        if checkpoint is not None and checkpoint.reused:
            result.counters_note = f"{checkpoint.reused} force evaluations reused from an interrupted run"
            progress.message(result.counters_note)
    result.timings.update(progress.timings)
    result.timings["total"] = time.perf_counter() - t_start
    if write and scene.write_hdf5:
        path = scene.output_dir / f"{scene.output_name}.h5"
        write_hdf5(result, path, scene.text)
        result.hdf5_path = str(path)
        if checkpoint is not None:
            checkpoint.discard()
    return result


def _scene_summary(scene: Scene, methods: dict[str, str]) -> dict[str, Any]:
    return {"file": str(scene.file) if scene.file else None, "solver": scene.solver,
            "master_modes": scene.master_modes, "methods": scene.methods,
            "evaluators": methods, "retained_modes": scene.retained_modes, "tensors": scene.tensors,
            "step": asdict(scene.step)}


def _run_modal_model(scene: Scene, model: ModalModel, progress: Progress) -> RunResult:
    omega = np.asarray(model.omegas(), dtype=float)
    labels = list(model.labels())
    m = len(omega)
    masters = resolve_masters(scene, labels, m, complete=True)
    assert masters is not None
    methods = resolve_methods(scene.methods, scene.qm_order or "modal")
    nret = scene.retained_modes
    scales = model.shell_scales()
    maxima = model.mode_maxima()
    tol = scene.tolerances
    modes = []
    with progress.stage("evaluators", "normal form and modal derivatives"):
        for p in masters:
            g = np.asarray(model.quadratic_coefficients(p), dtype=float)
            h = float(model.cubic_coefficient(p))
            groups = [s for s in range(m) if s != p and abs(omega[s] - omega[p]) <= scene.degeneracy_tolerance * omega[p]]
            rho, rho_mode = slow_fast_ratio(p, omega, g, tol, groups)
            rec = ModeResult(index=p, label=labels[p], omega=float(omega[p]), rho=rho, rho_mode=rho_mode,
                             omega_bar=scales.omega_bar(omega[p]) if scales else None,
                             w_max=float(maxima[p]) if maxima is not None else None)
            for name, ev in methods.items():
                # a modal model has no mesh: full order means every mode of the model
                if ev in FULL_METHODS or ev.endswith("_full"):
                    S = np.arange(m)
                    base = {"dnf": "nf", "md_full": "md_modal", "smd_full": "smd_modal"}[ev]
                    r = _modal_method(base, p, omega, g, h, S, tol, labels)
                    r.method, r.order = name, "all modes"
                else:
                    S = retained_set(p, nret, m)
                    r = _modal_method(ev, p, omega, g, h, S, tol, labels)
                    r.method = name
                if scales is not None:
                    r.gamma = scales.gamma(r.T, rec.w_max)
                rec.methods[name] = r
            modes.append(rec)
    return RunResult(scene=_scene_summary(scene, methods), modes=modes, counts=Counters().to_dict(),
                     timings={}, spectrum={"omega": omega.tolist(), "labels": labels, "n_rigid": 0,
                                           "degenerate_groups": []},
                     model=model.describe(), kappa=scales.kappa if scales else None)


def _run_adapter(scene: Scene, adapter: SolverAdapter, progress: Progress,
                 checkpoint: Checkpoint | None = None) -> RunResult:
    counters = Counters()
    tol = scene.tolerances
    n_ret = scene.retained_modes or 10
    methods = resolve_methods(scene.methods, scene.qm_order or "full")
    evaluators = set(methods.values())
    with progress.stage("matrices", "mass and stiffness matrices"):
        K = sp.csr_matrix(adapter.stiffness_matrix(), dtype=float)
        M = sp.csr_matrix(adapter.mass_matrix(), dtype=float)
    n = K.shape[0]
    if K.shape != (n, n) or M.shape != (n, n) or n != adapter.n_dofs:
        raise SceneError(scene.file, "model", f"the adapter returned K {K.shape} and M {M.shape} for "
                         f"{adapter.n_dofs} dofs")
    backend = choose_backend(n, scene.linear_solver)
    needs_modal = bool(evaluators & MODAL_METHODS) or scene.tensors == "full"
    int_masters = [m for m in scene.master_modes if isinstance(m, int)]
    need = max(int_masters, default=0) + 2
    if needs_modal:
        need = max(need, n_ret)
    label_cache: dict[int, list] = {}

    def labels_of(b: ModalBasis) -> list:
        key = b.n_elastic
        if key not in label_cache:
            label_cache.clear()
            label_cache[key] = list(adapter.mode_labels(b.phi))
        return label_cache[key]

    def enough(b: ModalBasis) -> bool:
        labs = labels_of(b) if any(isinstance(x, str) for x in scene.master_modes) else [None] * b.n_elastic
        ms = resolve_masters(scene, labs, b.n_elastic, complete=False)
        if ms is None:
            return False
        # the 1:1 checks need the modes just above the highest master (1:2 is checked locally)
        return b.complete or b.omega[-1] >= (1 + tol.resonance) * max(b.omega[i] for i in ms)

    eig = adapter.eigenmodes if adapter.provides_eigenmodes else None
    X, dirs = adapter.dof_coordinates(), adapter.dof_directions()
    cands = rigid_body_fields(X, dirs) if X is not None and dirs is not None else None
    with progress.stage("eigen", "modal analysis"):
        basis = modal_analysis(K, M, need, counters=counters, rigid_tolerance=scene.rigid_tolerance,
                               rigid_modes=scene.rigid_modes, degeneracy_tolerance=scene.degeneracy_tolerance,
                               max_modes=scene.max_modes, backend=backend, eigensolver=eig, enough=enough,
                               rigid_candidates=cands, progress=progress.message)
    labels = labels_of(basis) if any(isinstance(x, str) for x in scene.master_modes) else list(adapter.mode_labels(basis.phi))
    masters = resolve_masters(scene, labels, basis.n_elastic, complete=True)
    assert masters is not None
    omega, Phi = basis.omega, basis.phi
    m = basis.n_elastic
    run_flags: list[dict] = []
    if needs_modal and m < n_ret:
        run_flags.append({"kind": "fewer_modes", "message": f"only {m} elastic modes available, "
                          f"{n_ret} asked for in the modal sums"})

    # ---- STEP
    mask = None
    if dirs is not None:
        mask = np.asarray(dirs) < 3
    length = adapter.characteristic_length()
    forces = ForceEvaluator(adapter.internal_forces, n, counters,
                            batch_size=1024 if adapter.prefers_batches else 64, checkpoint=checkpoint)
    need_targeted = bool(evaluators & FULL_METHODS) or (bool(evaluators & MODAL_METHODS) and scene.tensors != "full")
    steps = {}
    policy = scene.step
    if policy.relative_amplitude is None and adapter.step_relative_amplitude is not None:
        policy = replace(policy, relative_amplitude=float(adapter.step_relative_amplitude))
    if policy.method == "tangent" and not adapter.provides_tangent_stiffness:
        raise SceneError(scene.file, "analysis.step.method",
                         f"'tangent' needs a solver that provides tangent stiffness; {scene.solver!r} does not. "
                         "Allowed here: ['forces']")
    if need_targeted:
        qs = np.array([step_amplitude(Phi[:, p], policy, length, mask) for p in masters])
        per = 4 if policy.check else 2
        if policy.method == "tangent":
            with progress.stage("step", f"STEP (targeted, tangent): {len(masters) * per} tangent stiffnesses"):
                for st in targeted_steps_tangent(adapter.tangent_stiffness, K, Phi[:, masters], qs, policy,
                                                 masters, counters):
                    steps[st.p] = st
        else:
            with progress.stage("step", f"STEP (targeted): {len(masters) * per} force evaluations"):
                for st in targeted_steps(forces, K, Phi[:, masters], qs, policy, masters):
                    steps[st.p] = st
    full = None
    arrays: dict[str, np.ndarray] = {"omega": omega, "master_modes": np.asarray(masters)}
    if scene.tensors == "full":
        Sfull = retained_set(max(masters), n_ret, m)
        qf = np.array([step_amplitude(Phi[:, s], policy, length, mask) for s in Sfull])
        with progress.stage("step_full", f"STEP (full plan) over {len(Sfull)} modes"):
            full = full_step(forces, K, Phi[:, Sfull], qf, policy, modes=Sfull,
                             progress=lambda d, t: progress.bar(d, t, "STEP"))
        arrays["g"], arrays["h"], arrays["full_modes"] = full.g, full.h, Sfull
        run_flags += full.flags

    # ---- evaluators
    shift_solver = adapter.shifted_solver if adapter.provides_shifted_solves else None
    ctx: FullOrderContext | None = None

    def context() -> FullOrderContext:
        nonlocal ctx
        if ctx is None:
            deflated = None
            if basis.factorization is not None and shift_solver is None and scene.deflation:
                # every shifted solve below the computed spectrum reuses the eigen-solver's factors
                F0 = basis.factorization
                deflated = DeflatedSolver(K, M, Phi, omega**2, basis.rigid, lambda b: F0.solve(b, count=False),
                                          counters)
                Kp = _DeflatedPinv(deflated, basis.rigid)
            else:
                Kp = PseudoInverse(K, M, basis.rigid, counters=counters, backend=backend,
                                   solver_factory=shift_solver)
            shifted = _adapter_shifted(shift_solver, n, counters) if shift_solver is not None else None
            ctx = FullOrderContext(K, M, Kp, counters, backend, shifted, deflated)
        return ctx

    scales = adapter.shell_scales()
    modes: list[ModeResult] = []
    with progress.stage("evaluators", "normal form and modal derivatives"):
        for p in masters:
            phi = Phi[:, p]
            twins = basis.twins(p)
            st = steps.get(p)
            if full is not None and p in list(arrays["full_modes"]):
                j = list(arrays["full_modes"]).index(p)
                g_mod = np.zeros(m)
                g_mod[arrays["full_modes"]] = full.g[:, j, j]
                h_mod = float(full.h[j, j, j, j])
                g_chk, h_chk = None, None
            else:
                g_mod = Phi.T @ st.Gv
                h_mod = st.h
                g_chk = Phi.T @ st.Gv_check if st.Gv_check is not None else None
                h_chk = st.h_check
            g_all = Phi.T @ st.Gv if st is not None else g_mod
            floor = coupling_floor(st, Phi, M, tol) if st is not None else None
            rho, rho_mode = slow_fast_ratio(p, omega, g_all, tol, twins, floor)
            w_max = adapter.transverse_amplitude(phi)
            rec = ModeResult(index=p, label=labels[p], omega=float(omega[p]), rho=rho, rho_mode=rho_mode,
                             omega_bar=scales.omega_bar(omega[p]) if scales else None, w_max=w_max)
            if st is not None:
                rec.step = {"amplitude": st.q, "check_amplitude": st.q_check, "error_G": st.error_G,
                            "error_h": st.error_h}
                rec.flags += st.flags
            y = None
            for name, ev in methods.items():
                if ev in MODAL_METHODS:
                    S = retained_set(p, n_ret, m)
                    r = _modal_method(ev, p, omega, g_mod, h_mod, S, tol, labels, floor)
                    if g_chk is not None:
                        r2 = _modal_method(ev, p, omega, g_chk, h_chk, S, tol, labels, floor)
                        r.T_error = _t_error(r.T, r2.T)
                    if st is not None:
                        r.flags += truncation_flags(r, st.Gv, g_all[S], M, len(S))
                elif ev == "dnf":
                    dG = st.Gv - st.Gv_check if st.Gv_check is not None else None
                    dh = st.h - st.h_check if st.h_check is not None else 0.0
                    r, y = dnf(p, phi, omega[p], st.Gv, st.h, context(), dGv=dG, dh=dh)
                    r.flags += _one_two_flags(p, omega[p], st, basis, context(), floor_scale(st, M, tol),
                                              tol, adapter, counters)
                elif ev == "smd_full":
                    r = smd_full(p, phi, omega[p], st.Gv, st.h, context(), y=y)
                    if st.Gv_check is not None:  # STEP sensitivity through the modal proxy over computed modes
                        S = np.arange(m)
                        a = smd_modal(p, omega, g_all, st.h, S, tol=tol, floor=floor)
                        b = smd_modal(p, omega, Phi.T @ st.Gv_check, st.h_check, S, tol=tol, floor=floor)
                        r.T_error = _t_error(a.T, b.T)
                elif ev == "md_full":
                    tw = Phi[:, twins] if twins else None
                    nr = basis.rigid.shape[1]
                    r = md_full(p, phi, omega[p], st.Gv, st.h, context(), tw, g=g_all, tol=tol, floor=floor,
                                exclude=[nr + p] + [nr + t for t in twins])
                    r.flags += _resonance_flags("md", p, omega, g_all,
                                                [s for s in range(m) if s not in twins], 1.0, tol, labels, floor)
                    if st.Gv_check is not None and np.isfinite(r.T):
                        S = np.array([s for s in range(m) if s not in twins])
                        a = md_modal(p, omega, g_all, st.h, S, tol=tol, floor=floor)
                        b = md_modal(p, omega, Phi.T @ st.Gv_check, st.h_check, S, tol=tol, floor=floor)
                        r.T_error = _t_error(a.T, b.T)
                else:  # pragma: no cover - resolve_methods only yields the above
                    raise KeyError(ev)
                r.method = name
                if ev in MODAL_METHODS:
                    r.retained_modes = len(retained_set(p, n_ret, m))
                if r.T_error is not None and r.T_error > policy.tolerance:
                    r.flags.append({"kind": "step_accuracy", "value": float(r.T_error),
                                    "message": f"T changes by {r.T_error:.2e} (relative) between the two "
                                               f"STEP amplitudes; tolerance {policy.tolerance:.1e}"})
                if scales is not None:
                    r.gamma = scales.gamma(r.T, w_max)
                rec.methods[name] = r
            modes.append(rec)
            arrays[f"Gv_{p}"] = st.Gv if st is not None else np.zeros(0)
    arrays["phi_masters"] = Phi[:, masters]
    if X is not None:
        arrays["dof_coordinates"] = np.asarray(X, dtype=float)
    if dirs is not None:
        arrays["dof_directions"] = np.asarray(dirs)
    spectrum = {"omega": omega.tolist(), "labels": labels, "n_rigid": int(basis.rigid.shape[1]),
                "rigid_eigenvalues": basis.rigid_eigenvalues.tolist(),
                "degenerate_groups": basis.degenerate_groups, "eigensolver": basis.solver,
                "linear_solver": backend}
    if scales is not None:
        spectrum["omega_bar"] = [scales.omega_bar(w) for w in omega]
    counts = counters.to_dict()
    counts["force_evaluations_reused"] = checkpoint.reused if checkpoint is not None else 0
    return RunResult(scene=_scene_summary(scene, methods), modes=modes, counts=counts,
                     timings={}, spectrum=spectrum, model=adapter.describe(),
                     kappa=scales.kappa if scales else None, flags=run_flags, arrays=arrays)
