"""What a scene asks of damping and forcing (``[analysis.damping]``, ``[analysis.forcing]``), parsed.

The scene reader fills these (keys checked there); :mod:`stepnf.forced.damping` and
:mod:`stepnf.forced.frc` use them. Model: ``M x'' + C x' + K x + G(x, x) + H(x, x, x) = F cos(Omega t)``.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DampingSpec:
    """``rayleigh = (alpha, beta)``: ``C = alpha M + beta K`` (alpha 1/time, beta time; both >= 0, not both 0);
    or ``modal``: the damping ratio of each master (one number for all, or one per master mode). One of
    the two is given, the other is None."""

    rayleigh: tuple[float, float] | None = None
    modal: tuple[float, ...] | float | None = None


@dataclass(frozen=True)
class LoadSpec:
    """Nodal forces ``F``: ``amplitude[i]`` (force units) on each of ``dofs`` of the nodes of the named
    ``set`` or of a ``box`` (as the boundary keys take them); one forcing level per amplitude."""

    set: str | None
    box: tuple | None
    dofs: tuple[str, ...]
    amplitude: tuple[float, ...]


@dataclass(frozen=True)
class ForcingSpec:
    """``modal``: levels ``k`` of ``F = k M phi_p cos(Omega t)`` (one FRC per level), or ``load``: nodal
    forces; ``frequency_range``: ``(lo, hi)`` of ``Omega / omega_p`` (contains 1); ``points``: samples of
    each FRC."""

    modal: tuple[float, ...] | None
    load: LoadSpec | None
    frequency_range: tuple[float, float]
    points: int = 400
