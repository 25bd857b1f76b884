"""STEP (Muravyov & Rizzi 2003): quadratic and cubic stiffness from prescribed displacements.

For a cubic internal force ``f(x) = K x + G(x, x) + H(x, x, x)`` and a field
``q phi``::

    f(+q phi) + f(-q phi) = 2 q^2 G(phi, phi)
    f(+q phi) - f(-q phi) = 2 q K phi + 2 q^3 H(phi, phi, phi)

*Targeted plan* (:func:`targeted_step`): two evaluations per master mode give
the whole vector ``G(phi_p, phi_p)`` (hence every ``g^s_pp``) and ``h^p_ppp``;
two more at a second amplitude give the error estimate.

*Full plan* (:func:`full_step`): Muravyov's combinations ``+-phi_j``,
``+-(phi_j + phi_k)``, ``phi_j - phi_k`` and ``phi_j + phi_k + phi_l`` give every
``g^p_jk`` and ``h^p_jkl`` of n retained modes in
``2n + 3n(n-1)/2 + n(n-1)(n-2)/6`` evaluations (+ ``2n`` for the check).

Amplitudes: ``q`` is chosen so that the largest translational displacement of
``q phi`` equals ``relative_amplitude`` times the model's characteristic length
(a shell's thickness), unless the scene gives ``amplitude`` (model length
units); a model with rotational dofs also keeps the largest rotation of ``q phi``
at most :data:`~stepnf.plugin.dofs.MAX_ROTATION` radians (rotations are no lengths). For an exact
cubic f, larger amplitudes only reduce round-off; for a
solver whose f is not an exact cubic, or prints few digits, the check at
``check_ratio * q`` measures what the amplitude costs; where its change stands above the forces'
rounding, a third amplitude measures the cubic fit's truncation and Richardson extrapolation removes it
(:mod:`stepnf.step.truncation`; targeted plan with forces only).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.flags import new_flag
from stepnf.plugin.dofs import MAX_ROTATION, bounded_scale, peak  # noqa: F401 (MAX_ROTATION re-exported)
from stepnf.runtime.counters import Counters
from stepnf.errors import NumericalError, StepnfError
from stepnf.step.forces import ForceEvaluator
from stepnf.step.truncation import gh_vectors, refine


@dataclass(frozen=True)
class StepPolicy:
    """How STEP amplitudes are chosen and checked (scene table ``[analysis.step]``)."""

    amplitude: float | None = None
    relative_amplitude: float | None = None  # None: the adapter's preference, else DEFAULT_RELATIVE_AMPLITUDE
    check_ratio: float = 0.5
    check: bool = True
    tolerance: float = 1e-4
    method: str = "forces"  # or "tangent": G and h from tangent stiffnesses at +-q phi


DEFAULT_RELATIVE_AMPLITUDE = 0.5
STEP_METHODS = ("forces", "tangent")




def step_amplitude(phi: np.ndarray, policy: StepPolicy, length: float | None,
                   mask: np.ndarray | None = None, rotations: np.ndarray | None = None) -> float:
    """Scale ``q`` of the field ``q phi`` sent to the solver (see module docstring).

    ``mask`` (bool (n,)): the translation dofs, whose largest entry of ``q phi`` is the target length
    (``None``, or none set: every dof); ``rotations`` (bool (n,), or ``None``): the rotation dofs (radians),
    whose largest entry of ``q phi`` is also kept at most :data:`~stepnf.plugin.dofs.MAX_ROTATION`, whatever
    the target: then ``q = min(target / max|phi_translation|, MAX_ROTATION / max|phi_rotation|)``
    (:func:`stepnf.plugin.dofs.bounded_scale`).
    """
    if mask is not None and not mask.any():
        mask = None  # no translation dofs: every dof
    if not peak(phi, mask) > 0 and not (rotations is not None and peak(phi, rotations) > 0):
        raise NumericalError("cannot choose a STEP amplitude for a zero mode shape")
    rel = policy.relative_amplitude if policy.relative_amplitude is not None else DEFAULT_RELATIVE_AMPLITUDE
    target = policy.amplitude if policy.amplitude is not None else rel * (length or 1.0)
    if not target > 0 or not np.isfinite(target):
        raise StepnfError(f"STEP amplitude must be a positive length, got {target!r}")
    # a mode of rotations only (a shell's drilling mode) is bounded by the rotation bound alone
    return bounded_scale(phi, target, mask, rotations)


@dataclass
class MasterStep:
    """Targeted STEP result for one master mode (vectors in the solver's dof ordering).

    ``Gv = G(phi_p, phi_p)`` (n,), ``h = phi_p^T H(phi_p, phi_p, phi_p)`` at the
    amplitude ``q``; the ``*_check`` values at ``q_check``; ``error_G`` and
    ``error_h`` the relative differences (scaled as described in
    :func:`targeted_step`).
    """

    p: int
    q: float
    Gv: np.ndarray
    h: float
    q_check: float | None = None
    Gv_check: np.ndarray | None = None
    h_check: float | None = None
    error_G: float = 0.0
    error_h: float = 0.0
    flags: list[dict] = field(default_factory=list)
    #: ``H(phi_p, phi_p, phi_p)`` (n,) and at the check amplitude (for the twins' cubic coupling)
    Hv: np.ndarray | None = None
    Hv_check: np.ndarray | None = None
    #: the amplitudes run when the check found the force not an exact cubic (:mod:`stepnf.step.truncation`;
    #: ``q`` and ``q_check`` are then those whose rounding the kept values carry), and the observed rates
    #: of the changes of ``Gv`` and ``h`` (2: the cubic fit's truncation); empty, None otherwise
    amplitudes: tuple[float, ...] = ()
    rate_G: float | None = None
    rate_h: float | None = None
    #: how many times the changes that grew as the amplitude shrank (rounding: a negative rate,
    #: :func:`stepnf.step.truncation.rounding_excess`) exceeded their rounding bound: rounding the per-entry
    #: model of :mod:`stepnf.nf.roundoff` did not foresee, by which T's rounding bound is scaled (1: none shown)
    rounding_excess: float = 1.0


def targeted_step(forces: ForceEvaluator, K: sp.spmatrix, phi: np.ndarray, q: float,
                  policy: StepPolicy, p: int = 0) -> MasterStep:
    """``G(phi, phi)`` and ``h = phi^T H(phi, phi, phi)`` from two (four with the check) evaluations.

    Error estimates are relative to the size of the nonlinear forces at the
    STEP amplitude, so they stay meaningful when G vanishes by symmetry:
    ``error_G = q ||dGv|| / ||K phi||`` (the change of the quadratic force at
    the STEP amplitude, relative to the linear force) and ``error_h`` the
    larger of ``|dh| / |h|`` (round-off at small amplitudes; h does not vanish
    by symmetry) and ``q^2 |dh| / (phi^T K phi)`` (the change of the cubic force
    relative to the linear one, which grows with the amplitude for a force
    that is not an exact cubic), where d is the difference between the two
    amplitudes.
    """
    return targeted_steps(forces, K, phi[:, None], np.asarray([q]), policy, [p])[0]


def targeted_steps(forces: ForceEvaluator, K: sp.spmatrix, Phi: np.ndarray, q: np.ndarray,
                   policy: StepPolicy, modes: list[int] | None = None, plan: str = "targeted",
                   digits: int | None = None) -> list[MasterStep]:
    """:func:`targeted_step` for several master modes (columns of ``Phi``) in ONE batch of fields.

    An external solver then runs once for the whole plan (``plan``: its name in the run's checkpoint).
    With the check amplitude, a master whose two amplitudes differ by more than the forces' rounding
    (``digits``: the solver's printed force digits, None: double precision) is a force that is not an exact
    cubic: a third amplitude measures the cubic fit's truncation and the values kept balance it against
    the rounding (:mod:`stepnf.step.truncation`, one more batch).
    """
    k = Phi.shape[1]
    modes = list(range(k)) if modes is None else list(modes)
    per = 4 if policy.check else 2
    fields = []
    for j in range(k):
        phi, qj = Phi[:, j], float(q[j])
        fields += [qj * phi, -qj * phi]
        if policy.check:
            q2 = policy.check_ratio * qj
            fields += [q2 * phi, -q2 * phi]
    F = forces(np.stack(fields), plan=plan)
    out, Kphis = [], []
    for j in range(k):
        phi, qj, p = Phi[:, j], float(q[j]), modes[j]
        Kphi = K @ phi
        Kphis.append(Kphi)
        Fj = F[per * j: per * (j + 1)]
        Gv, Hv = gh_vectors(Fj[0], Fj[1], Kphi, qj)
        res = MasterStep(p=p, q=qj, Gv=Gv, h=float(phi @ Hv), Hv=Hv)
        if policy.check:
            q2 = policy.check_ratio * qj
            res.Gv_check, res.Hv_check = gh_vectors(Fj[2], Fj[3], Kphi, q2)
            res.q_check, res.h_check = q2, float(phi @ res.Hv_check)
        out.append(res)
    if not policy.check:
        return out
    if 0.0 < policy.check_ratio < 1.0:
        refine(forces, K, Phi, out, policy.check_ratio, digits, policy.tolerance, plan, np.column_stack(Kphis))
    for j, res in enumerate(out):
        phi, Kphi = Phi[:, j], Kphis[j]
        qj, p, h, h2, q2 = float(q[j]), res.p, res.h, res.h_check, float(res.q_check)
        lin = max(float(np.linalg.norm(Kphi)), 1e-300)
        w2 = max(float(phi @ Kphi), 1e-300)
        res.error_G = qj * float(np.linalg.norm(res.Gv - res.Gv_check)) / lin
        res.error_h = max(_relative(h, h2), qj * qj * abs(h - h2) / w2)
        if any(f.get("kind") == "step_unconverged" for f in res.flags):
            continue  # step_unconverged says it (a smaller amplitude, not a larger one)
        for name, err in (("G", res.error_G), ("h", res.error_h)):
            if not np.isfinite(err) or err > policy.tolerance:
                res.flags.append(new_flag(
                    "step_accuracy",
                    message=f"STEP {name} of mode {p} changes by {err:.2e} (relative) between "
                            f"amplitudes {res.q:.3e} and {q2:.3e}; tolerance {policy.tolerance:.1e}",
                    mode=p, value=float(err),
                ))
    return out


def targeted_steps_tangent(tangent: Callable[[np.ndarray], sp.spmatrix], K: sp.spmatrix, Phi: np.ndarray,
                           q: np.ndarray, policy: StepPolicy, modes: list[int] | None = None,
                           counters: Counters | None = None) -> list[MasterStep]:
    """Targeted STEP from tangent stiffnesses instead of forces (exact for a cubic f)::

        K_T(q phi) - K_T(-q phi) = 4 q G(phi, .)        K_T(q phi) + K_T(-q phi) - 2 K = 6 q^2 H(phi, phi, .)

    For a solver whose tangent carries more digits than its printed forces
    (CalculiX: 14 against 7), this sharpens G and h by orders of magnitude.
    Two tangents per master mode (four with the check amplitude).
    """
    from stepnf.plugin.adapter import checked_matrix

    owner = getattr(tangent, "__self__", tangent)
    out = []
    modes = list(range(Phi.shape[1])) if modes is None else list(modes)
    for j, p in enumerate(modes):
        phi, qj = Phi[:, j], float(q[j])

        def gh(a: float) -> tuple[np.ndarray, float, np.ndarray]:
            # the adapter's tangents enter here: real, (n, n), finite and symmetric, else AdapterError
            Kp, Km = (checked_matrix(tangent(s * phi), "K_T", owner, K.shape[0])
                      for s in (a, -a))
            if counters is not None:
                counters.tangent_evaluations += 2
            Gv = (Kp - Km) @ phi / (4.0 * a)
            X = (Kp + Km - 2.0 * K) @ phi  # 6 a^2 H(phi, phi, phi)
            # h divided after the product, as before H was kept: the last bits of h (and results) unchanged
            h = float(phi @ X) / (6.0 * a * a)
            return np.asarray(Gv).ravel(), h, np.asarray(X).ravel() / (6.0 * a * a)

        Gv, h, Hv = gh(qj)
        res = MasterStep(p=p, q=qj, Gv=Gv, h=h, Hv=Hv)
        if policy.check:
            q2 = policy.check_ratio * qj
            Gv2, h2, res.Hv_check = gh(q2)
            Kphi = K @ phi
            res.q_check, res.Gv_check, res.h_check = q2, Gv2, h2
            res.error_G = qj * float(np.linalg.norm(Gv - Gv2)) / max(float(np.linalg.norm(Kphi)), 1e-300)
            res.error_h = max(_relative(h, h2), qj * qj * abs(h - h2) / max(float(phi @ Kphi), 1e-300))
        out.append(res)
    return out


def _relative(x: float, y: float) -> float:
    """``|x - y| / |x|`` (0 when both vanish)."""
    d = abs(x - y)
    return d / abs(x) if x != 0 else (0.0 if d == 0 else float("inf"))


def n_full_step_evaluations(n: int) -> int:
    """Force evaluations of the full Muravyov-Rizzi plan for ``n`` modes (no check)."""
    return 2 * n + 3 * n * (n - 1) // 2 + n * (n - 1) * (n - 2) // 6


@dataclass
class FullStep:
    """All modal coefficients of ``n`` retained modes.

    ``g[p, j, k] = phi_p^T G(phi_j, phi_k)``, ``h[p, j, k, l] = phi_p^T H(phi_j, phi_k, phi_l)``
    (symmetric in the lower indices); ``error`` the largest scaled change of
    the diagonal terms between the two amplitudes.
    """

    modes: np.ndarray
    q: np.ndarray
    g: np.ndarray
    h: np.ndarray
    error: float = 0.0
    flags: list[dict] = field(default_factory=list)
    g_norm2: dict[int, float] = field(default_factory=dict)  # column j -> norm2(G(phi_j, phi_j)), see full_step


def full_step(forces: ForceEvaluator, K: sp.spmatrix, Phi: np.ndarray, q: np.ndarray,
              policy: StepPolicy, modes: np.ndarray | None = None,
              progress: Callable[[int, int], None] | None = None,
              norm2: Callable[[np.ndarray], float] | None = None,
              norm_columns: Sequence[int] = ()) -> FullStep:
    """Full STEP plan on the columns of ``Phi`` (n_dof, n) with per-mode amplitudes ``q`` (n,).

    The combinations use scaled modes ``v_j = q_j phi_j``; every force is
    projected on the modes at once, so memory stays O(n^3) whatever the
    model size. With ``norm2`` (a squared norm of a force vector, e.g. the
    ``M^-1`` norm), ``FullStep.g_norm2[j]`` is ``norm2(G(phi_j, phi_j))`` for
    each ``j`` in ``norm_columns``, measured on the whole vector before its
    projection (what the modal truncation check needs), at no extra force
    evaluation.
    """
    n = Phi.shape[1]
    V = Phi * q  # scaled modes
    KV = K @ V
    proj = Phi.T  # (n, n_dof)
    # field list: (+j), (-j), (j+k), -(j+k), (j-k), (j+k+l)
    pairs = list(itertools.combinations(range(n), 2))
    triples = list(itertools.combinations(range(n), 3))
    U_rows: list[np.ndarray] = []
    for j in range(n):
        U_rows += [V[:, j], -V[:, j]]
    for j, k in pairs:
        s, d = V[:, j] + V[:, k], V[:, j] - V[:, k]
        U_rows += [s, -s, d]
    for j, k, l in triples:
        U_rows.append(V[:, j] + V[:, k] + V[:, l])
    total = len(U_rows)
    P = np.empty((total, n + 1))  # forces projected on the modes; last column: norm2 of G(v_j, v_j)
    wanted = {2 * j for j in norm_columns}

    def reduce(F: np.ndarray, start: int) -> np.ndarray:
        extra = np.zeros(len(F))
        for r in range(0, len(F) - 1, 2):
            if norm2 is not None and start + r in wanted:  # rows +v_j, -v_j: G(v_j, v_j) = (f+ + f-) / 2
                extra[r] = norm2((F[r] + F[r + 1]) / 2.0)
        return np.column_stack([F @ proj.T, extra])

    for b, (i, stop) in enumerate(forces.blocks(total)):  # a plan of its own per block, so progress can be shown
        P[i:stop] = forces(np.stack(U_rows[i:stop]), plan=f"full{b:05d}", reduce=lambda F, i=i: reduce(F, i))
        if progress:
            progress(stop, total)
    del U_rows
    g_norm2 = {j: float(P[2 * j, n]) / q[j] ** 4 for j in norm_columns}
    P = P[:, :n]
    KVp = (proj @ KV)  # (n, n): modal linear forces of scaled modes
    G2 = np.zeros((n, n, n))  # projected G(v_j, v_k)
    H3 = np.zeros((n, n, n, n))  # projected H(v_j, v_k, v_l)
    Hjjj = np.zeros((n, n))
    row = 0
    for j in range(n):
        fp, fm = P[row], P[row + 1]
        row += 2
        G2[:, j, j] = (fp + fm) / 2.0
        Hjjj[:, j] = (fp - fm) / 2.0 - KVp[:, j]
        H3[:, j, j, j] = Hjjj[:, j]
    for j, k in pairs:
        fs, fms, fd = P[row], P[row + 1], P[row + 2]
        row += 3
        # f(s)+f(-s) = 2 G(s,s) = 2 (Gjj + 2Gjk + Gkk)
        Gjk = ((fs + fms) / 2.0 - G2[:, j, j] - G2[:, k, k]) / 2.0
        G2[:, j, k] = G2[:, k, j] = Gjk
        odd_s = (fs - fms) / 2.0 - KVp[:, j] - KVp[:, k]  # Hjjj + 3Hjjk + 3Hjkk + Hkkk
        # f(d) = K d + G(d,d) + H(d,d,d);  H(d)^3 = Hjjj - 3Hjjk + 3Hjkk - Hkkk
        odd_d = fd - (KVp[:, j] - KVp[:, k]) - (G2[:, j, j] - 2 * Gjk + G2[:, k, k])
        a = (odd_s - Hjjj[:, j] - Hjjj[:, k]) / 3.0  # Hjjk + Hjkk
        b = (odd_d - Hjjj[:, j] + Hjjj[:, k]) / 3.0  # -Hjjk + Hjkk
        Hjjk, Hjkk = (a - b) / 2.0, (a + b) / 2.0
        for idx in set(itertools.permutations((j, j, k))):
            H3[(slice(None),) + idx] = Hjjk
        for idx in set(itertools.permutations((j, k, k))):
            H3[(slice(None),) + idx] = Hjkk
    for j, k, l in triples:
        f = P[row]
        row += 1
        lin_part = KVp[:, j] + KVp[:, k] + KVp[:, l]
        quad = (G2[:, j, j] + G2[:, k, k] + G2[:, l, l]
                + 2 * (G2[:, j, k] + G2[:, j, l] + G2[:, k, l]))
        cub_known = (Hjjj[:, j] + Hjjj[:, k] + Hjjj[:, l]
                     + 3 * (H3[:, j, j, k] + H3[:, j, j, l] + H3[:, k, k, j]
                            + H3[:, k, k, l] + H3[:, l, l, j] + H3[:, l, l, k]))
        Hjkl = (f - lin_part - quad - cub_known) / 6.0
        for idx in itertools.permutations((j, k, l)):
            H3[(slice(None),) + idx] = Hjkl
    # undo the amplitude scaling: G(v_j, v_k) = q_j q_k G(phi_j, phi_k)
    g = G2 / (q[None, :, None] * q[None, None, :])
    h = H3 / (q[None, :, None, None] * q[None, None, :, None] * q[None, None, None, :])
    res = FullStep(modes=np.arange(n) if modes is None else np.asarray(modes), q=q, g=g, h=h, g_norm2=g_norm2)
    if policy.check:
        q2 = policy.check_ratio * q
        V2 = Phi * q2
        U2 = np.concatenate([V2.T, -V2.T])
        F2 = forces(U2, plan="fullcheck", reduce=lambda F: F @ proj.T)
        KV2p = proj @ (K @ V2)
        err = 0.0
        w2 = np.maximum(np.abs(np.diag(KVp) / q ** 2), 1e-300)
        for j in range(n):
            gp = (F2[j] + F2[n + j]) / (2 * q2[j] ** 2)
            hp = ((F2[j] - F2[n + j]) / 2 - KV2p[:, j]) / q2[j] ** 3
            eg = q[j] * np.linalg.norm(gp - g[:, j, j]) / np.sqrt(w2[j]) / max(np.sqrt(w2[j]), 1e-300)
            eh = q[j] ** 2 * abs(hp[j] - h[j, j, j, j]) / w2[j]
            err = max(err, float(eg), float(eh))
        res.error = err
        if not np.isfinite(err) or err > policy.tolerance:
            res.flags.append(new_flag("step_accuracy",
                                      message=f"full STEP coefficients change by {err:.2e} between amplitudes",
                                      value=float(err)))
    return res
