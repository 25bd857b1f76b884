"""The backbone coefficient T of the reduced dynamics of one master mode (paper Eq. 6-7).

    R'' + w^2 R + C1 R^2 + C2 R'^2/w^2 + C3 R'' R/w^2
        + C4 R^3 + C5 R'^2 R/w^2 + C6 R'' R^2/w^2 = 0

    T = -(10 C1^2 + 10 C1 C2 + 4 C2^2 - 7 C2 C3 + C3^2 - 11 C1 C3) / (24 w^4)
        + (3 C4 + C5 - 3 C6) / (8 w^2)

so that ``w_NL = w (1 + T a^2)`` for a response of amplitude ``a`` of the
master coordinate; ``T > 0`` hardening, ``T < 0`` softening.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from stepnf.flags import json_safe, t_unusable


def backbone_T(C: Sequence[float], omega: float) -> float:
    """Eq. (7): T from the six coefficients ``C = (C1, ..., C6)`` and the angular frequency."""
    C1, C2, C3, C4, C5, C6 = (float(c) for c in C)
    w2 = omega * omega
    quad = 10 * C1**2 + 10 * C1 * C2 + 4 * C2**2 - 7 * C2 * C3 + C3**2 - 11 * C1 * C3
    return -quad / (24.0 * w2 * w2) + (3 * C4 + C5 - 3 * C6) / (8.0 * w2)


def qm_coefficients(omega: float, g_p: float, h: float, mu1: float, mu2: float,
                    k2: float, t: float) -> tuple[float, ...]:
    """C1..C6 of a quadratic manifold ``u = phi R + theta R^2 / 2`` by Galerkin projection.

    With ``mu1 = phi^T M theta``, ``mu2 = theta^T M theta``, ``k2 = theta^T K theta``,
    ``t = theta^T G(phi, phi)``, ``g_p = phi^T G(phi, phi)``, ``h = phi^T H(phi, phi, phi)``,
    projecting ``M u'' + f(u) = 0`` on ``du/dR = phi + theta R`` gives

    ``C1 = 3/2 w^2 mu1 + g_p``, ``C2 = w^2 mu1``, ``C3 = 2 w^2 mu1``,
    ``C4 = k2/2 + 2 t + h``, ``C5 = C6 = w^2 mu2``,

    which reduces to the MD and SMD rows of Table 1 when theta is expanded on
    the modes.
    """
    w2 = omega * omega
    return (1.5 * w2 * mu1 + g_p, w2 * mu1, 2 * w2 * mu1, 0.5 * k2 + 2 * t + h, w2 * mu2, w2 * mu2)


@dataclass
class MethodResult:
    """T of one master mode by one method, with its coefficients and flags.

    ``T`` is in the model's own units (1/length^2 for an M-normalised FE mode
    shape: ``w_NL = w (1 + T a^2)`` with ``a`` the modal amplitude);
    ``T`` is ``+inf``/``-inf`` where the method diverges (flagged), never NaN.
    ``T_error`` estimates the relative error of T due to STEP (from the check
    amplitude), ``gamma`` is Gamma when the model is a shell.

    ``fields`` holds the full-order evaluators' displacement vectors (n,) in
    the model's dof order, named and normalised as :mod:`stepnf.nf.evaluators`
    documents (``a_bar``, ``w2_b_bar``, ``theta``); they are for the
    ParaView output (:mod:`stepnf.io.fields`) and are neither in :meth:`to_dict`
    (JSON) nor in the HDF5 results file.
    """

    method: str
    T: float
    C: tuple[float, ...]
    flags: list[dict[str, Any]] = field(default_factory=list)
    order: str = "modal"
    retained_modes: int | None = None
    T_error: float | None = None
    gamma: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    fields: dict[str, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    @property
    def behaviour(self) -> str:
        """"hardening", "softening" or "linear" by T's sign; "diverges" for an infinite T (a zero
        denominator gives no trend), "undetermined" for NaN."""
        if math.isnan(self.T):
            return "undetermined"
        if math.isinf(self.T):
            return "diverges"
        return "hardening" if self.T > 0 else ("softening" if self.T < 0 else "linear")

    def to_dict(self) -> dict[str, Any]:
        """The JSON form: the numbers kept (infinite ones as "inf"/"-inf"), the flags, and ``na``: why the
        table shows T as n/a (:func:`stepnf.flags.t_unusable`), or null."""
        verdict = t_unusable(self)
        d: dict[str, Any] = {
            "T": json_float(self.T),
            "C": [json_float(c) for c in self.C],
            "flags": json_safe(self.flags),
            "na": None if verdict is None else {"kind": verdict[0], "reason": verdict[1]},
            "behaviour": self.behaviour,
            "order": self.order,
            "retained_modes": self.retained_modes,
            "T_error": json_float(self.T_error),
            "gamma": json_float(self.gamma),
        }
        d.update({k: json_float(v) if isinstance(v, float) else v for k, v in self.extra.items()})
        return d


def json_float(x: float | None) -> float | str | None:
    """A float for JSON: ``inf`` and ``-inf`` become the strings ``"inf"``/``"-inf"``; NaN is refused."""
    if x is None:
        return None
    x = float(x)
    if math.isnan(x):
        raise ValueError("stepnf never reports NaN: a NaN reached the results")
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return x


def finite_or_signed_inf(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """``num / den`` with a zero denominator giving ``+-inf`` by the numerator's sign (0/0 gives 0)."""
    num = np.asarray(num, dtype=float)
    den = np.asarray(den, dtype=float)
    out = np.zeros(np.broadcast(num, den).shape)
    nz = den != 0
    np.divide(num, den, out=out, where=nz)
    z = ~nz & (num != 0)
    out[z] = np.inf * np.sign(num[z])
    return out
