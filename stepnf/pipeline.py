"""Run a scene: adapter -> modal analysis -> evaluation plan -> STEP -> evaluators -> results.

Only what the scene asks for is computed: NF/DNF/MD/SMD of one master mode
need the targeted STEP (two force evaluations, four with the amplitude check),
whatever the model size; the full STEP over the retained modes runs only when
``analysis.tensors = "full"``.
"""
from __future__ import annotations

import contextlib
import time
import warnings
from dataclasses import asdict, replace
from typing import Any

import numpy as np

from .adapter import SolverAdapter, checked_matrices
from .backbone import MethodResult
from .checkpoint import Checkpoint
from .counters import Counters
from .deflation import DeflatedSolver
from .diagnostics import (captured_share, check_conditioning, conditioning_flags, conditioning_ratio, coupling_floor,
                          floor_scale, inverse_mass_norm2, merge_flags, one_two_flags, overflow_is_numerical,
                          slow_fast_ratio, smooth_eigenvalue, soft_mode_flags, t_error, truncation_flags)
from .errors import ModelWarning, SceneError
from .evaluators import (FullOrderContext, dnf, md_full, md_modal, nf_modal, resonance_flags, retained_set,
                         smd_full, smd_modal)
from .gamma import NO_AMPLITUDE, gamma_scale
from .linalg import Factorization, PseudoInverse, apply_columns, choose_backend
from .modal import (ModalBasis, lambda_scale, modal_analysis, orient_degenerate, probe_vector,
                    rigid_body_fields)
from .modal_model import ModalModel
from .plan import check_elastic_modes, check_mechanism, check_rigid_count, resolve_masters, resolve_methods
from .progress import Progress
from .registry import build_model, get_solver
from .results import ModeResult, RunResult, write_hdf5
from .scene import Scene
from .step import ForceEvaluator, full_step, step_amplitude, targeted_steps, targeted_steps_tangent

MODAL_METHODS = {"nf", "md_modal", "smd_modal"}
FULL_METHODS = {"dnf", "md_full", "smd_full"}


def _adapter_shifted(shift_solver, n: int, counters: Counters):
    """The adapter's own ``K - sigma M`` factorisations, as :class:`Factorization` objects."""
    def shifted(sigma: float, label: str) -> Factorization:
        counters.factorizations += 1
        raw = shift_solver(sigma)
        return Factorization(lambda b: apply_columns(raw, b), n, "adapter", counters, label)
    return shifted


class _DeflatedPinv:
    """``K^+`` through a :class:`DeflatedSolver` (same interface as :class:`PseudoInverse`)."""

    def __init__(self, solver: DeflatedSolver, R: np.ndarray):
        self.solver, self.R = solver, R

    def __call__(self, b: np.ndarray) -> np.ndarray:
        return self.solver.pinv(b)


def _modal_method(name: str, p: int, omega, g, h, S, tol, labels, floor=None) -> MethodResult:
    if name == "nf":
        return nf_modal(p, omega, g, h, S, tol=tol, labels=labels, floor=floor)
    if name == "md_modal":
        return md_modal(p, omega, g, h, S, tol=tol, labels=labels, floor=floor)
    if name == "smd_modal":
        return smd_modal(p, omega, g, h, S, tol=tol, labels=labels, floor=floor)
    raise KeyError(name)


def run_scene(scene: Scene, *, progress: Progress | None = None, write: bool = True) -> RunResult:
    """Compute what ``scene`` asks for and return (and, with ``write``, store) the results.

    With ``write``, the output folder is checked first (before any solver work): a folder that
    is a file, read-only or cannot be created is a :class:`SceneError` on ``output.dir``. A
    results file that cannot be written at the end (full disk) raises
    :class:`stepnf.errors.OutputError` whose ``result`` holds what was computed; the checkpoint
    folder is removed in both cases, and a previous results file is left untouched.
    """
    from .atomic import check_folder
    from .errors import OutputError

    progress = progress or Progress(enabled=False)
    writing = write and scene.write_hdf5
    created = writing and not scene.output_dir.exists()
    if writing:
        why = check_folder(scene.output_dir)
        if why is not None:
            raise SceneError(scene.file, "output.dir", f"the output folder {scene.output_dir} is not "
                             f"usable: {why}")
    t_start = time.perf_counter()
    try:
        result, checkpoint = _compute(scene, progress, writing)
    except BaseException:
        if created:  # a folder this run made and left empty (a checkpoint to resume from is kept)
            with contextlib.suppress(OSError):
                scene.output_dir.rmdir()
        raise
    result.timings.update(progress.timings)
    result.timings["total"] = time.perf_counter() - t_start
    if writing:
        path = scene.output_dir / f"{scene.output_name}.h5"
        try:
            write_hdf5(result, path, scene.text)
        except OutputError as exc:
            exc.result = result  # computed, not stored: the caller can still show it
            raise
        finally:
            if checkpoint is not None:  # the results are computed: the chunks are of no more use
                checkpoint.discard()
        result.hdf5_path = str(path)
    return result


def _compute(scene: Scene, progress: Progress, writing: bool) -> tuple[RunResult, Checkpoint | None]:
    """Build the model and run the pipeline; the force checkpoint (when writing) goes with the result."""
    cls = get_solver(scene.solver)
    checkpoint = None
    if issubclass(cls, ModalModel):
        with progress.stage("model", f"building the {scene.solver} model"):
            model = build_model(scene)
        try:
            return _run_modal_model(scene, model, progress), None
        finally:
            model.close()
    with progress.stage("model", f"setting up the {scene.solver} model"):
        adapter = build_model(scene)
    # no checkpoint for an adapter whose calls are collective over MPI ranks: a rank that
    # reused stored forces would skip calls the other ranks make (rank 0 alone writes)
    if writing and not adapter.collective:
        checkpoint = Checkpoint(scene.output_dir / f".{scene.output_name}.partial")
    try:
        result = _run_adapter(scene, adapter, progress, checkpoint)
    finally:
        adapter.close()
    if checkpoint is not None and checkpoint.reused:
        result.counters_note = f"{checkpoint.reused} force evaluations reused from an interrupted run"
        progress.message(result.counters_note)
    return result, checkpoint


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
        K, M = checked_matrices(adapter)  # real, (n, n), finite, symmetric: else AdapterError (exit 3)
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

    policy = scene.step
    if policy.relative_amplitude is None and adapter.step_relative_amplitude is not None:
        policy = replace(policy, relative_amplitude=float(adapter.step_relative_amplitude))
    if policy.method == "tangent" and not adapter.provides_tangent_stiffness:
        raise SceneError(scene.file, "analysis.step.method",
                         f"'tangent' needs a solver that provides tangent stiffness; {scene.solver!r} does not. "
                         "Allowed here: ['forces']")
    eig = adapter.eigenmodes if adapter.provides_eigenmodes else None
    X, dirs = adapter.dof_coordinates(), adapter.dof_directions()
    cands = rigid_body_fields(X, dirs) if X is not None and dirs is not None else None
    check_rigid_count(scene, n)
    smooth = smooth_eigenvalue(K, M, X, dirs)  # refuse a hopelessly ill-conditioned model before solving
    if smooth is not None:
        check_conditioning(conditioning_ratio(smooth, K, M))
    with progress.stage("eigen", "modal analysis"):
        basis = modal_analysis(K, M, need, counters=counters, rigid_tolerance=scene.rigid_tolerance,
                               rigid_modes=scene.rigid_modes, degeneracy_tolerance=scene.degeneracy_tolerance,
                               max_modes=scene.max_modes, backend=backend, eigensolver=eig, enough=enough,
                               rigid_candidates=cands, progress=progress.message)
    check_elastic_modes(scene, basis)
    check_mechanism(scene, adapter, basis)
    orient_degenerate(basis, M, probe_vector(X, dirs, n))  # the same twins whatever the solver
    label_cache.clear()
    labels = labels_of(basis)
    masters = resolve_masters(scene, labels, basis.n_elastic, complete=True)
    assert masters is not None
    omega, Phi = basis.omega, basis.phi
    m = basis.n_elastic
    run_flags: list[dict] = conditioning_flags(basis, K, M, smooth)
    if scene.rigid_modes is None:  # a count the user gave is theirs to keep
        for fl in soft_mode_flags(basis.rigid_eigenvalues, lambda_scale(K, M), scene.rigid_tolerance):
            warnings.warn(fl["message"], ModelWarning, stacklevel=2)
            run_flags.append(fl)
    if needs_modal and m < n_ret:
        run_flags.append({"kind": "fewer_modes", "message": f"only {m} elastic modes available, "
                          f"{n_ret} asked for in the modal sums"})

    # ---- STEP
    mask = None
    if dirs is not None:
        mask = np.asarray(dirs) < 3
    length = scene.thickness if scene.thickness is not None else adapter.characteristic_length()
    if length is None and policy.amplitude is None:
        run_flags.append({"kind": "no_length", "message": "the model gives no characteristic length (no dof "
                          "coordinates): STEP amplitudes are relative_amplitude x 1 model length unit; set "
                          "[analysis] thickness or [analysis.step] amplitude"})
    forces = ForceEvaluator(adapter.internal_forces, n, counters,
                            batch_size=1024 if adapter.prefers_batches else 64, checkpoint=checkpoint)
    need_targeted = bool(evaluators & FULL_METHODS) or (bool(evaluators & MODAL_METHODS) and scene.tensors != "full")
    steps = {}
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
            # the M^-1 norm of each master's G(phi_p, phi_p), for the modal-truncation flag
            full = full_step(forces, K, Phi[:, Sfull], qf, policy, modes=Sfull,
                             progress=lambda d, t: progress.bar(d, t, "STEP"),
                             norm2=lambda v: inverse_mass_norm2(M, v),
                             norm_columns=[list(Sfull).index(p) for p in masters if p in list(Sfull)])
        arrays["g"], arrays["h"], arrays["full_modes"] = full.g, full.h, Sfull
        run_flags += full.flags

    # ---- evaluators
    shift_solver = adapter.shifted_solver if adapter.provides_shifted_solves else None
    ctx: FullOrderContext | None = None

    def context() -> FullOrderContext:
        nonlocal ctx
        if ctx is None:
            deflated = None
            precond = None
            if basis.factorization is not None and shift_solver is None and scene.deflation:
                # every shifted solve below the computed spectrum reuses the eigen-solver's factors
                F0 = basis.factorization
                precond = lambda b: F0.solve(b, count=False)  # noqa: E731
            elif shift_solver is not None and scene.deflation and basis.n_elastic and not basis.complete:
                # the same with ONE factorisation by the solver (e.g. distributed, under MPI), which then
                # serves every solve below the computed spectrum, bordered modal-derivative systems included
                counters.factorizations += 1
                precond = shift_solver(-1e-10 * lambda_scale(K, M))
            if precond is not None:
                deflated = DeflatedSolver(K, M, Phi, omega**2, basis.rigid, precond, counters)
                Kp = _DeflatedPinv(deflated, basis.rigid)
            else:
                Kp = PseudoInverse(K, M, basis.rigid, counters=counters, backend=backend,
                                   solver_factory=shift_solver)
            shifted = _adapter_shifted(shift_solver, n, counters) if shift_solver is not None else None
            ctx = FullOrderContext(K, M, Kp, counters, backend, shifted, deflated)
        return ctx

    scales = adapter.shell_scales()
    gscale, no_gamma = gamma_scale(scene, adapter, X, dirs)
    modes: list[ModeResult] = []
    where = {"stage": "evaluators"}
    with overflow_is_numerical(where, steps), progress.stage("evaluators", "normal form and modal derivatives"):
        for p in masters:
            where.update(master=int(p), method="(diagnostics)")
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
            w_max = gscale.amplitude(phi) if gscale is not None else adapter.transverse_amplitude(phi)
            rec = ModeResult(index=p, label=labels[p], omega=float(omega[p]), rho=rho, rho_mode=rho_mode,
                             omega_bar=scales.omega_bar(omega[p]) if scales else None, w_max=w_max)
            if st is not None:
                rec.step = {"amplitude": st.q, "check_amplitude": st.q_check, "error_G": st.error_G,
                            "error_h": st.error_h}
                rec.flags += st.flags
            y = None
            for name, ev in methods.items():
                where.update(master=int(p), method=name)
                if ev in MODAL_METHODS:
                    S = retained_set(p, n_ret, m)
                    r = _modal_method(ev, p, omega, g_mod, h_mod, S, tol, labels, floor)
                    if g_chk is not None:
                        r2 = _modal_method(ev, p, omega, g_chk, h_chk, S, tol, labels, floor)
                        r.T_error = t_error(r.T, r2.T)
                    frac = captured_share(p, st, full, g_all, S, M)
                    if frac is not None:
                        r.flags += truncation_flags(r, frac, len(S))
                elif ev == "dnf":
                    dG = st.Gv - st.Gv_check if st.Gv_check is not None else None
                    dh = st.h - st.h_check if st.h_check is not None else 0.0
                    r, y = dnf(p, phi, omega[p], st.Gv, st.h, context(), dGv=dG, dh=dh)
                    r.flags = merge_flags(r.flags, one_two_flags(p, omega[p], st, basis, context(),
                                                                 floor_scale(st, M, tol), tol, adapter, counters))
                elif ev == "smd_full":
                    r = smd_full(p, phi, omega[p], st.Gv, st.h, context(), y=y)
                    if st.Gv_check is not None:  # T again at the check amplitude: one more K^+ solve
                        r.T_error = t_error(r.T, smd_full(p, phi, omega[p], st.Gv_check, st.h_check, context()).T)
                elif ev == "md_full":
                    tw = Phi[:, twins] if twins else None
                    nr = basis.rigid.shape[1]
                    kw = dict(g=g_all, tol=tol, floor=floor, exclude=[nr + p] + [nr + t for t in twins],
                              twin_index=twins, labels=labels)
                    r = md_full(p, phi, omega[p], st.Gv, st.h, context(), tw, **kw)
                    r.flags += resonance_flags("md", p, omega, g_all,
                                               [s for s in range(m) if s not in twins], 1.0, tol, labels, floor)
                    if st.Gv_check is not None and np.isfinite(r.T):  # T again at the check amplitude
                        r2 = md_full(p, phi, omega[p], st.Gv_check, st.h_check, context(), tw, **kw)
                        r.T_error = t_error(r.T, r2.T)
                else:  # pragma: no cover - resolve_methods only yields the above
                    raise KeyError(ev)
                r.method = name
                if ev in MODAL_METHODS:
                    r.retained_modes = len(retained_set(p, n_ret, m))
                if r.T_error is not None and r.T_error > policy.tolerance:
                    r.flags.append({"kind": "step_accuracy", "value": float(r.T_error),
                                    "message": f"T changes by {r.T_error:.2e} (relative) between the two "
                                               f"STEP amplitudes; tolerance {policy.tolerance:.1e}"})
                if gscale is not None:
                    r.gamma = gscale.gamma(r.T, w_max)
                rec.methods[name] = r
            modes.append(rec)
            arrays[f"Gv_{p}"] = st.Gv if st is not None else np.zeros(0)

    if not any(r.gamma is not None for rec in modes for r in rec.methods.values()):
        run_flags.append({"kind": "no_gamma", "message": no_gamma or NO_AMPLITUDE})
    arrays["phi_masters"] = Phi[:, masters]
    free = adapter.free_dof_map()
    if free is not None:  # fields over the whole mesh: full = zeros(n_full_dofs); full[free_dofs] = field
        arrays["free_dofs"] = np.asarray(free.free, dtype=np.int64)
        arrays["n_full_dofs"] = np.asarray(free.n_full, dtype=np.int64)
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
    model = adapter.describe()
    if gscale is not None:
        model["gamma"] = gscale.source
    return RunResult(scene=_scene_summary(scene, methods), modes=modes, counts=counts,
                     timings={}, spectrum=spectrum, model=model,
                     kappa=scales.kappa if scales else None, flags=run_flags, arrays=arrays)
