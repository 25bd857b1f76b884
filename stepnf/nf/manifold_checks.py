"""Whether a master mode has a single-mode invariant manifold at all: the tests behind T and the backbone.

Every method (NF, DNF, MD, SMD) and the DPIM backbone reduce the dynamics to one master mode. That
reduction does not exist, and every number it gives is wrong (not merely inaccurate), when the
master's own nonlinear forces drive, at the frequency they oscillate with,

* **a degenerate twin** (a mode of the same frequency, 1:1 resonance): the cubic force
  ``H(phi_p, phi_p, phi_p)`` has a component ``h^t_ppp = phi_t^T H(phi_p, phi_p, phi_p)`` on the twin
  ``t``. Its first harmonic then forces the twin exactly at resonance (the DPIM's own test,
  :mod:`stepnf.dpim.solves`, refuses the order-3 solve for the same reason); the backbones of the pair
  lie along other directions of its eigenspace, with other T (a two-mode reduction is needed);
* **a zero-frequency mode** (one counted or declared rigid): the quadratic force
  ``G(phi_p, phi_p)`` has a component ``R^T G(phi_p, phi_p)`` on it. Its mean (harmonic 0) forces a
  mode of zero stiffness: the mean of the motion grows without bound, no periodic orbit exists. A
  true rigid-body motion is never driven (internal forces are self-equilibrated): such a mode is a
  mechanism or a missing support.

Thresholds as for every coupling (:func:`stepnf.nf.diagnostics.coupling_floor`): a component counts when it
exceeds ``analysis.coupling_tolerance`` (default 1e-5) times the size of the force it is a component of
(lumped ``M^-1`` norm, which bounds the component along any M-normalised mode) and ten times its change
between the two STEP amplitudes (the solver's noise): couplings that a mesh's imperfect symmetry
creates (~1e-6) stay below, physical ones (1e-2 and more) far above. The flags
(``twin_driven``, ``rigid_mode_driven``, :mod:`stepnf.flags`) make T n/a in the table for every method
of the master and take every validity range from its backbone.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.flags import new_flag
from stepnf.nf.evaluators import Tolerances
from stepnf.linalg.factorization import matrix_diagonal


def _lumped_norm(M: sp.spmatrix, v: np.ndarray) -> float:
    """``sqrt(v^T diag(M)^-1 v)`` (bounds ``|phi^T v|`` for M-normalised ``phi`` up to the lumping)."""
    dm = matrix_diagonal(M)
    return float(np.sqrt(np.sum(v ** 2 / np.where(dm > 0, dm, np.inf))))


def driven(components: np.ndarray, force: np.ndarray, check: np.ndarray | None, modes: np.ndarray,
           M: sp.spmatrix, tol: Tolerances) -> np.ndarray:
    """Indices ``j`` where ``|components[j]|`` (``modes[:, j]^T force``) exceeds the coupling floor: ``tol.coupling``
    times the lumped ``M^-1`` norm of ``force``, and ten times the change of the component at the check
    amplitude (``check``: the same force there, or None)."""
    floor = np.full(len(components), tol.coupling * _lumped_norm(M, force))
    if check is not None:
        floor = np.maximum(floor, 10.0 * np.abs(modes.T @ (force - check)))
    return np.flatnonzero(np.abs(components) > floor)


def twin_flags(p: int, st: Any, Phi: np.ndarray, twins: Sequence[int], M: sp.spmatrix, tol: Tolerances,
               labels: Sequence[Any] | None = None) -> list[dict]:
    """``twin_driven`` flags of master ``p`` (module docstring): ``st`` its :class:`stepnf.step.procedure.MasterStep`
    (``Hv`` needed; none without), ``Phi`` the elastic modes, ``twins`` the indices of its degenerate twins."""
    if st is None or getattr(st, "Hv", None) is None or not twins:
        return []
    T = Phi[:, list(twins)]
    c = T.T @ st.Hv
    size = _lumped_norm(M, st.Hv)
    flags = []
    for j in driven(c, st.Hv, getattr(st, "Hv_check", None), T, M, tol):
        t = int(twins[j])
        lab = f" {labels[t]}" if labels is not None and labels[t] is not None else ""
        ratio = abs(float(c[j])) / size if size > 0 else float("inf")
        flags.append(new_flag("twin_driven", mode=t, value=ratio,
                              message=f"mode {t}{lab}, a degenerate twin of master mode {p} (same frequency), is "
                                      f"driven by the master's cubic force (h^t_ppp = {float(c[j]):.3e}, {ratio:.2e} "
                                      "of its size): a single-mode invariant manifold does not exist (1:1 internal "
                                      "resonance); its backbones lie along other directions of the pair, with other T: "
                                      "a two-mode reduction is needed"))
    return flags


def rigid_flags(p: int, st: Any, R: np.ndarray, M: sp.spmatrix, tol: Tolerances, *, declared: bool) -> list[dict]:
    """``rigid_mode_driven`` flags of master ``p`` (module docstring): ``R`` the modes set aside as rigid
    (n, r), M-normalised; ``declared``: their count came from ``analysis.rigid_modes`` (else from their
    eigenvalues)."""
    if st is None or R is None or not R.shape[1]:
        return []
    c = R.T @ st.Gv
    size = _lumped_norm(M, st.Gv)
    how = "declared by analysis.rigid_modes" if declared else "counted as rigid by its eigenvalue"
    flags = []
    for j in driven(c, st.Gv, st.Gv_check, R, M, tol):
        ratio = abs(float(c[j])) / size if size > 0 else float("inf")
        flags.append(new_flag("rigid_mode_driven", mode=None, rigid_mode=int(j), value=ratio,
                              message=f"master mode {p} drives rigid mode {int(j)} (zero frequency, {how}): its "
                                      f"quadratic force has a component {ratio:.2e} of its size along it, so the mean "
                                      "of the motion drifts and no periodic orbit exists (neither T nor a backbone). "
                                      "Internal forces never drive a true rigid-body motion: this zero-frequency mode "
                                      "is a mechanism or a missing support; hold it ([[model.boundary]])"))
    return flags
