"""Models given directly in modal coordinates (no FE mesh, no STEP).

A :class:`ModalModel` is the second kind of plugin under ``stepnf.solvers``
(beside :class:`stepnf.plugin.adapter.SolverAdapter`): it hands the evaluators the
natural frequencies ``omega_s`` and the coupling coefficients ``g^s_pp`` and
``h^p_ppp`` of Eq. (3) of the paper, in its own normalisation. The von Karman
shell model (:mod:`stepnf.models`) and analytic test systems are of this kind.
"""
from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from stepnf.keys.schema import FromScene


class ModalModel(FromScene):
    """Base class of models known by their modal coefficients.

    Conventions: modes are indexed 0..m-1 by increasing frequency and contain
    no rigid-body mode; ``omega`` are angular frequencies in the model's own
    time unit; ``g^s_pp`` and ``h^p_ppp`` are the coefficients of
    ``X_p'' + omega_p^2 X_p + sum g^p_ij X_i X_j + sum h^p_ijk X_i X_j X_k = 0``.
    """

    name: ClassVar[str] = ""

    def close(self) -> None:
        """Release resources. Idempotent."""

    @property
    def n_modes(self) -> int:
        """Number of modes the model holds."""
        return len(self.omegas())

    def omegas(self) -> np.ndarray:
        """Angular frequencies (m,), increasing."""
        raise NotImplementedError

    def labels(self) -> list[Any]:
        """Label of each mode, e.g. ``(k, n)``, or ``None``."""
        return [None] * self.n_modes

    def quadratic_coefficients(self, p: int) -> np.ndarray:
        """``g^s_pp`` for every mode s (m,)."""
        raise NotImplementedError

    def cubic_coefficient(self, p: int) -> float:
        """``h^p_ppp``."""
        raise NotImplementedError

    def mode_maxima(self) -> np.ndarray | None:
        """Largest transverse displacement of each mode shape (m,), for Gamma; ``None`` when unknown."""
        return None

    def shell_scales(self) -> Any | None:
        """Shell scales (:class:`stepnf.plugin.shell_scales.ShellScales`) when the model is a shell, else ``None``."""
        return None

    def describe(self) -> dict[str, Any]:
        """Facts worth storing with the results (JSON-serialisable)."""
        return {"model": type(self).__name__, "n_modes": int(self.n_modes)}
