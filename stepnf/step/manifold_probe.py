"""STEP along the quadratic manifold: the condensed cubic term of a slender structure, without its cancellation.

DNF's ``A + h`` of a slender structure is a small difference of large terms (docs/design.md section 1,
"Round-off of T"): the membrane stretching of the mode (``h``) is almost entirely relaxed by the
membrane displacement ``-q^2 y``, ``y = K^+ G(phi, phi)`` (``A``). Along the manifold
``u(s) = s phi - s^2 y`` the solver computes the relaxed forces itself, so a force printed with few
digits (CalculiX: 7) no longer carries the large membrane forces whose difference T is. With
``S(s) = f(u(s))^T u'(s)`` (``u' = phi - 2 s y``, the derivative of the potential along ``u``)::

    [S(s) - S(-s)] / 2 = s w^2 + s^3 h_s + s^5 c_5 + s^7 c_7         (f an exact cubic)
    h_s = h - 2 y^T G(phi, phi)                                        (the condensed cubic term)

The ``s^3`` coefficient is stationary in ``y`` (an error ``e`` of the solve changes it by ``2 e^T K e``).
The linear coefficient is FITTED, not taken as ``phi^T K phi``: the solver's own linear force differs
from its assembled matrix by ``~ eps |phi|^T |K| |phi|`` (6e-4 of ``w^2`` for a cantilever's first mode at
L/h = 1000), which subtracted would leave ``delta / s^2`` in ``h_s``. Eight amplitudes ``t_k = s 2^(-k/2)``,
k = 0..7 (sixteen force evaluations, one batch): ``Q(t) = [S(t) - S(-t)] / (2 t) = a1 + h_s t^2 + c5 t^4
+ c7 t^6`` is fitted by least squares (exact for a cubic f). The error estimate is
:data:`STANDARD_ERRORS` standard errors of ``h_s`` from the fit's residuals (four degrees of freedom:
Student's t exceeds 10 with a probability of 6e-4; measured on a two-dof case with uniform rounding of
its element forces: 2 of 2000 draws beyond it, by at most 3%), which sees the rounding that is not
smooth in ``t`` and a force that is not an exact cubic, plus, for a solver that
prints ``force_digits``, the bound of that printing (:func:`~stepnf.nf.roundoff.weighted_rounding`:
independent roundings, 5 standard deviations) through the fit's weights. Measured on a FEniCSx strip at
L/h = 1000 (first mode): ``h_s`` equal to 9 digits at every ``s`` from 5 to 200 thicknesses, where the
STEP at ``+-q phi`` had none.
DNF's T is then ``3 h_s / (8 w^2) - y^T M z`` (``B = 4 y^T M z``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stepnf.nf.roundoff import printed_rounding, weighted_rounding
from stepnf.step.forces import ForceEvaluator

#: the probe's amplitudes, as fractions of its largest
FRACTIONS = tuple(2.0 ** (-k / 2) for k in range(8))
#: the error estimate of ``h_s``: this many standard errors of the least-squares fit
STANDARD_ERRORS = 10.0


@dataclass(frozen=True)
class ManifoldProbe:
    """The condensed cubic term of one master: ``h_s`` (model units, for a mass-normalised phi), its
    error estimate ``dh_s`` (absolute: module docstring), ``standard_error`` of the fit (absolute), and
    the largest amplitude ``s`` (modal)."""

    h_s: float
    dh_s: float
    standard_error: float
    s: float


def manifold_probe(forces: ForceEvaluator, phi: np.ndarray, y: np.ndarray, s: float,
                   digits: int | None, plan: str | None) -> ManifoldProbe:
    """``h_s`` of master ``phi`` (mass-normalised) from forces along ``u = t phi - t^2 y``, ``t = +-s 2^(-k/2)``
    (module docstring); ``digits``: the solver's printed force digits (None: double precision)."""
    fields, tangents = [], []
    for a in FRACTIONS:
        t = a * s
        for sign in (1.0, -1.0):
            fields.append(sign * t * phi - t * t * y)
            tangents.append(phi - 2.0 * sign * t * y)
    F = forces(np.stack(fields), plan=plan)
    ts = s * np.asarray(FRACTIONS)
    Q = np.array([(float(F[2 * k] @ tangents[2 * k]) - float(F[2 * k + 1] @ tangents[2 * k + 1])) / (2.0 * t)
                  for k, t in enumerate(ts)])
    eps_f = printed_rounding(digits)
    dQ = np.array([weighted_rounding(np.concatenate([tangents[2 * k], tangents[2 * k + 1]]), np.zeros(2 * len(phi)),
                                     eps_f * np.abs(np.concatenate([F[2 * k], F[2 * k + 1]]))) / (2.0 * t)
                   for k, t in enumerate(ts)])
    # Q = a1 + a3 x + a5 x^2 + a7 x^3 in x = (t / s)^2; h_s = a3 / s^2
    V = np.vander((ts / s) ** 2, 4, increasing=True)
    coef, *_ = np.linalg.lstsq(V, Q, rcond=None)
    dof = len(Q) - 4
    sigma2 = float(np.sum((Q - V @ coef) ** 2)) / dof
    weights = np.linalg.pinv(V)[1]  # h_s s^2 = weights @ Q
    se = float(np.sqrt(sigma2 * np.sum(weights ** 2))) / s ** 2
    h_s = float(coef[1]) / s ** 2
    bound = float(np.abs(weights) @ dQ) / s ** 2
    return ManifoldProbe(h_s, STANDARD_ERRORS * se + bound, se, float(s))
