"""What the evaluators know of one master mode: its STEP coefficients and its diagnostics."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stepnf.nf.diagnostics import coupling_floor, slow_fast_ratio
from stepnf.io.results import ModeResult
from stepnf.step.procedure import MasterStep
from stepnf.pipeline.state import StageView


@dataclass
class MasterData:
    """One master mode ``p`` as the methods see it.

    ``g_mod``, ``h_mod``: modal coefficients g^s_pp (every elastic mode s) and h^p_ppp for the modal
    sums, from the full STEP when it covers ``p``, else from the targeted STEP; ``g_chk``, ``h_chk``:
    the same at the check amplitude (None without one). ``g_all``: g^s_pp from the targeted STEP
    where there is one. ``floor``: the coupling below which a g is STEP noise (None without targeted
    STEP). ``y``: ``K^+ Gv``, DNF's first solve, reused by ``smd_full`` of the same master; ``z``: DNF's
    ``(K - 4 w_p^2 M)^-1 b``; ``theta``: MD's deflated solve. ``y``, ``z``, ``theta`` are None until
    solved (:mod:`stepnf.pipeline.prefetch` solves them for every master at once where it can).
    """

    p: int
    phi: np.ndarray
    twins: list[int]
    st: MasterStep | None
    g_mod: np.ndarray
    h_mod: float
    g_chk: np.ndarray | None
    h_chk: float | None
    g_all: np.ndarray
    floor: np.ndarray | float | None
    w_max: float | None = None
    y: np.ndarray | None = None
    z: np.ndarray | None = None
    theta: np.ndarray | None = None


def master_data(state: StageView, p: int) -> MasterData:
    """Gather master ``p``'s coefficients. Reads ``basis``, ``steps``, ``full`` and its modes, ``M``."""
    Phi, st, full = state.phi, state.steps.get(p), state.full
    if full is not None and p in list(state.terms.full_modes):
        j = list(state.terms.full_modes).index(p)
        g_mod = np.zeros(state.m)
        g_mod[state.terms.full_modes] = full.g[:, j, j]
        h_mod = float(full.h[j, j, j, j])
        g_chk, h_chk = None, None
    else:
        g_mod = Phi.T @ st.Gv
        h_mod = st.h
        g_chk = Phi.T @ st.Gv_check if st.Gv_check is not None else None
        h_chk = st.h_check
    g_all = Phi.T @ st.Gv if st is not None else g_mod
    floor = coupling_floor(st, Phi, state.M, state.tol) if st is not None else None
    return MasterData(p, Phi[:, p], state.basis.twins(p), st, g_mod, h_mod, g_chk, h_chk, g_all, floor)


def mode_record(state: StageView, d: MasterData) -> ModeResult:
    """The result record of master ``d.p`` before its methods: frequency, rho, W_max, STEP accuracy.

    Reads ``basis``, ``labels``, ``tol``, ``gscale`` or the adapter's transverse amplitude, ``scales``.
    Sets ``d.w_max`` (largest transverse displacement of the mode shape, model length units).
    """
    p, omega, st = d.p, state.omega, d.st
    rho, rho_mode = slow_fast_ratio(p, omega, d.g_all, state.tol, d.twins, d.floor)
    d.w_max = state.gscale.amplitude(d.phi) if state.gscale is not None else state.adapter.transverse_amplitude(d.phi)
    rec = ModeResult(index=p, label=state.labels[p], omega=float(omega[p]), rho=rho, rho_mode=rho_mode,
                     omega_bar=state.scales.omega_bar(omega[p]) if state.scales else None, w_max=d.w_max)
    if st is not None:
        rec.step = {"amplitude": st.q, "check_amplitude": st.q_check, "error_G": st.error_G,
                    "error_h": st.error_h}
        if st.amplitudes:  # a force that is not an exact cubic: the third amplitude and the observed rates
            rec.step.update(amplitudes=list(st.amplitudes), rate_G=st.rate_G, rate_h=st.rate_h)
        if st.rounding_excess > 1.0:  # rounding beyond the model's bound, shown by the changes themselves
            rec.step["rounding_excess"] = st.rounding_excess
        rec.flags += st.flags
    return rec
