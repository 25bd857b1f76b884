"""Damping of the model ``M x'' + C x' + K x + ... = F cos(Omega t)``: ratios, ``C v`` products, ``omega_d``.

Two forms (:class:`stepnf.forced.spec.DampingSpec`):

* Rayleigh ``C = alpha M + beta K``: the damping ratio of a mode of angular frequency ``w`` is
  ``xi = alpha / (2 w) + beta w / 2`` (``alpha`` 1/time, ``beta`` time, model units);
* modal: a damping ratio ``xi_j`` for each master ``j``; ``C = sum_j 2 xi_j w_j M phi_j phi_j^T M``
  (``phi_j`` M-normalised), which damps the masters only.

The damped frequency of a master is ``omega_d = omega sqrt(1 - xi^2)``. No damping at all (an unbounded
forced peak) and ``xi >= 1`` (overdamped: no resonance to follow) are refused, naming the scene key.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from stepnf.errors import SceneError
from stepnf.forced.spec import DampingSpec

KEY = "analysis.damping"


def check_spec(spec: DampingSpec) -> None:
    """Refuse a spec with no damping, both forms, a negative coefficient or a non-finite one."""
    if (spec.rayleigh is None) == (spec.modal is None):
        raise SceneError(None, KEY, "give one of 'rayleigh = [alpha, beta]' or 'modal = xi' "
                                    f"(got {'both' if spec.rayleigh is not None else 'neither'})")
    if spec.rayleigh is not None:
        ab = np.asarray(spec.rayleigh, dtype=float)
        if ab.shape != (2,) or not np.all(np.isfinite(ab)) or np.any(ab < 0) or not np.any(ab > 0):
            raise SceneError(None, KEY + ".rayleigh",
                             f"[alpha, beta] must be two finite numbers >= 0, not both 0 (no damping: an "
                             f"unbounded forced peak); got {list(spec.rayleigh)}")
    else:
        xs = np.atleast_1d(np.asarray(spec.modal, dtype=float))
        if xs.size == 0 or not np.all(np.isfinite(xs)) or np.any(xs <= 0) or np.any(xs >= 1):
            raise SceneError(None, KEY + ".modal",
                             f"damping ratios must be > 0 (zero damping: an unbounded forced peak) and < 1 "
                             f"(xi >= 1 is overdamped: no resonance); got {spec.modal}")


def damping_ratio(spec: DampingSpec, omega: float, master: int = 0) -> float:
    """The damping ratio ``xi`` of the master of index ``master`` (in the scene's master list), angular
    frequency ``omega`` (rad per model time unit). SceneError when the master is overdamped (xi >= 1)."""
    check_spec(spec)
    if spec.rayleigh is not None:
        alpha, beta = (float(v) for v in spec.rayleigh)
        xi = alpha / (2.0 * omega) + beta * omega / 2.0
        if xi >= 1.0:
            raise SceneError(None, KEY + ".rayleigh",
                             f"mode of w = {omega:.6g} rad/time is overdamped (xi = alpha/(2w) + beta w/2 = "
                             f"{xi:.4g} >= 1): no resonance to follow; lower alpha or beta")
        return xi
    xs = np.atleast_1d(np.asarray(spec.modal, dtype=float))
    if xs.size == 1:
        return float(xs[0])
    if not 0 <= master < xs.size:
        raise SceneError(None, KEY + ".modal", f"{xs.size} damping ratios given, none for master {master}: "
                                               f"give one per master mode, or one number for all")
    return float(xs[master])


def damped_frequency(omega: float, xi: float) -> float:
    """``omega_d = omega sqrt(1 - xi^2)``; SceneError for ``xi >= 1`` (overdamped)."""
    if not 0.0 < xi < 1.0:
        raise SceneError(None, KEY, f"damping ratio xi = {xi:.4g}: allowed 0 < xi < 1 (0: unbounded peak, "
                                    f">= 1: overdamped)")
    return float(omega * np.sqrt(1.0 - xi * xi))


class Damping:
    """The damping operator ``C`` of a model, applied to fields (module docstring).

    ``M``, ``K`` (n, n) dense or sparse (``K`` needed for Rayleigh's ``beta``); ``masters``: the master
    modes ``[(phi_j (n,), w_j), ...]`` in the scene's order (needed for modal damping, and for
    :meth:`ratio`). ``C @ v`` or ``C(v)`` for ``v`` (n,) or (k, n) rows of fields.
    """

    def __init__(self, spec: DampingSpec, M: Any, K: Any = None,
                 masters: Sequence[tuple[np.ndarray, float]] = ()):
        check_spec(spec)
        self.spec, self.M, self.K = spec, M, K
        self.masters = [(np.asarray(phi, dtype=float), float(w)) for phi, w in masters]
        if spec.rayleigh is not None and spec.rayleigh[1] > 0 and K is None:
            raise ValueError("Rayleigh damping with beta > 0 needs the stiffness K")
        if spec.modal is not None:
            if not self.masters:
                raise ValueError("modal damping needs the master modes (masters=[(phi, w), ...])")
            self.xi = [damping_ratio(spec, w, j) for j, (_, w) in enumerate(self.masters)]
            self._Mphi = np.column_stack([M @ phi for phi, _ in self.masters])  # (n, m)

    def ratio(self, master: int = 0, omega: float | None = None) -> float:
        """Damping ratio of master ``master`` (its frequency, or ``omega`` when given)."""
        w = self.masters[master][1] if omega is None else float(omega)
        return damping_ratio(self.spec, w, master)

    def __call__(self, v: np.ndarray) -> np.ndarray:
        V = np.asarray(v, dtype=float)
        rows = np.atleast_2d(V)  # (k, n)
        if self.spec.rayleigh is not None:
            alpha, beta = (float(x) for x in self.spec.rayleigh)
            out = alpha * np.asarray(self.M @ rows.T).T
            if beta:
                out = out + beta * np.asarray(self.K @ rows.T).T
        else:
            gain = np.asarray([2.0 * xi * w for xi, (_, w) in zip(self.xi, self.masters)])
            out = (rows @ self._Mphi * gain) @ self._Mphi.T
        return out[0] if V.ndim == 1 else out

    def __matmul__(self, v: np.ndarray) -> np.ndarray:
        return self(v)
