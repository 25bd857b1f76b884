"""Nondimensional figures of shallow spherical shells (docs/design.md, "Comparing models").

* aspect ratio ``kappa = a^4 / (R^2 h^2)`` (0 for the flat plate, R = inf);
* nondimensional frequency ``w_bar = w a^2 sqrt(rho h / D)``, ``D = E h^3 / (12 (1 - nu^2))``;
* ``Gamma``: coefficient of ``(W_max/h)^2`` in ``w_NL / w = 1 + Gamma (W_max/h)^2``,
  i.e. ``Gamma = T (h / max|phi_w|)^2`` for a mode shape ``phi`` whose largest
  transverse mid-surface displacement is ``max|phi_w|`` (a translation: a shell's
  rotation dofs, radians, never enter it, :mod:`stepnf.plugin.dofs`).

``h`` is also the length the automatic STEP amplitude is relative to
(:func:`stepnf.step.procedure.step_amplitude`, through the adapter's
``characteristic_length``): a shell adapter, whose mid-surface mesh has no
thickness extent, returns its ``h`` there.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any


@dataclass(frozen=True)
class ShellScales:
    """Scales that turn a model's own T and omega into kappa, w_bar and Gamma.

    ``omega_factor`` multiplies an angular frequency to give w_bar;
    ``thickness`` is h in the model's length unit (1 for a nondimensional model).
    """

    kappa: float
    omega_factor: float
    thickness: float

    @classmethod
    def from_geometry(cls, *, a: float, R: float, h: float, E: float, nu: float, rho: float) -> "ShellScales":
        """Scales of a cap of outer radius ``a``, curvature radius ``R`` (``inf``: plate), thickness ``h``."""
        D = E * h**3 / (12.0 * (1.0 - nu**2))
        kappa = 0.0 if math.isinf(R) else a**4 / (R**2 * h**2)
        return cls(kappa=kappa, omega_factor=a**2 * math.sqrt(rho * h / D), thickness=h)

    def omega_bar(self, omega: float) -> float:
        """Nondimensional angular frequency."""
        return omega * self.omega_factor

    def gamma(self, T: float, w_max: float | None) -> float | None:
        """Gamma from T (model units) and the mode's largest transverse displacement."""
        if w_max is None or not w_max > 0:
            return None
        return T * (self.thickness / w_max) ** 2

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
