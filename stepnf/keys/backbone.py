"""The scene table ``[analysis.backbone]``: the DPIM backbone of every master mode (:mod:`stepnf.pipeline.backbone`).

::

    [analysis.backbone]
    order = 7                  # odd, 3..25 (default 7): the parametrisation's order N
    amplitudes = [1e-3, 2e-3]  # optional: amplitudes A of q_p = phi_p^T M x (model units), > 0, ascending
    w_over_h = [0.5, 1.0]      # optional: W_max / h values (needs a thickness and transverse dofs)
    tolerance = 1e-3           # relative difference of orders N-2 and N that ends the validity range
    points = 40                # grid size when neither list is given (a grid up to the validity limit)
    manifolds = [[0, 4]]       # optional: masters on manifolds of several modes, or "auto" (stepnf.keys.manifolds)
    resonance = 0.05           # optional, with manifolds: the tolerance on their small denominators
    ratios = [[1, 4]]          # optional, with explicit manifolds: the resonance vector of each ([] : found)

Declared as a :class:`stepnf.keys.schema.Schema`, so a misspelt key, a wrong type or a value out of
range is a :class:`~stepnf.errors.SceneError` naming the key when the scene is read (exit 2).
Whether a thickness is known for ``w_over_h`` is decided by the model, hence checked at run time.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stepnf.keys.checks import check_number, describe_value
from stepnf.errors import SceneError
from stepnf.keys.manifolds import check_manifolds, check_ratios, check_resonance, check_scene_manifolds
from stepnf.keys.schema import Key, Schema

#: Orders: 3 (DNF's T) up to 25; the force evaluations grow like N^3.5 (``stepnf.dpim.nonlinear_terms.planned_evaluations``:
#: 176 per mode at 7, 2336 at 15), 25 already costs ~1.5e4 per mode, and the series' radius of convergence
#: rarely rewards more.
ORDER_RANGE = (3, 25)
#: Amplitudes are lengths in model units (the range of ``[analysis.step] amplitude``); W_max/h up to 1e3
#: thicknesses (beyond, no thin structure stays elastic); both lists at most 1000 values (each one root find).
AMPLITUDE_RANGE = (1e-15, 1e15)
W_OVER_H_RANGE = (1e-12, 1e3)
MAX_VALUES = 1000
#: The grid: 2 points at least (a curve), 10 000 at most (each point a root find on the amplitude).
POINTS_RANGE = (2, 10_000)
#: The validity tolerance: a relative difference of two orders' frequencies, above the round-off of the
#: polarised forces (~1e-13 of the frequency on an exact polynomial model, more on FE models).
TOLERANCE_RANGE = (1e-10, 1.0)
DEFAULT_ORDER = 7


@dataclass(frozen=True)
class BackboneSpec:
    """What ``[analysis.backbone]`` asks: ``order`` N, the ``amplitudes`` or ``w_over_h`` values at which
    to report (None: a grid of ``points`` up to the validity limit), the validity ``tolerance``."""

    order: int = DEFAULT_ORDER
    amplitudes: tuple[float, ...] | None = None
    w_over_h: tuple[float, ...] | None = None
    tolerance: float = 1e-3
    points: int = 40
    manifolds: str | tuple[tuple[int | str, ...], ...] | None = None
    resonance: float | None = None
    ratios: tuple[tuple[int, ...] | None, ...] | None = None


def _odd(file: Any, key: str, value: Any) -> int:
    lo, hi = ORDER_RANGE
    v = int(check_number(file, key, value, integer=True, lo=lo, hi=hi, why=" (an odd order)"))
    if v % 2 == 0:
        raise SceneError(file, key, f"the order must be odd (3, 5, 7, ...), got {v}")
    return v


def _ascending(rng: tuple[float, float], what: str):
    def check(file: Any, key: str, value: Any) -> tuple[float, ...]:
        if not isinstance(value, list) or not value or len(value) > MAX_VALUES:
            raise SceneError(file, key, f"expected a non-empty list (at most {MAX_VALUES}) of {what}, "
                             f"got {describe_value(value)}")
        out = tuple(float(check_number(file, f"{key}[{i}]", v, lo=rng[0], hi=rng[1], why=f" ({what})"))
                    for i, v in enumerate(value))
        if any(b <= a for a, b in zip(out, out[1:])):
            raise SceneError(file, key, f"the values must be strictly ascending, got {list(out)}")
        return out
    return check


BACKBONE_KEYS = Schema(
    Key("order", "custom", "odd order N of the parametrisation (3..25)", default=DEFAULT_ORDER,
        check_value=_odd, what="an odd integer in [3, 25]"),
    Key("amplitudes", "custom", "amplitudes A of q_p (model length units) at which w_NL is reported",
        check_value=_ascending(AMPLITUDE_RANGE, "amplitudes A > 0, model length units"),
        what="ascending list of A > 0"),
    Key("w_over_h", "custom", "W_max / h values at which w_NL is reported (needs a thickness)",
        check_value=_ascending(W_OVER_H_RANGE, "values of W_max / h > 0"), what="ascending list of W_max/h > 0"),
    Key("tolerance", "number", "relative difference of orders N-2 and N that ends the validity range",
        default=1e-3, lo=TOLERANCE_RANGE[0], hi=TOLERANCE_RANGE[1],
        why=" (a relative difference; below 1e-10 two orders differ by round-off)"),
    Key("points", "integer", "grid size without a list", default=40, lo=POINTS_RANGE[0], hi=POINTS_RANGE[1]),
    Key("manifolds", "custom", "sets of modes whose masters get the backbone of their manifold, or \"auto\"",
        check_value=check_manifolds, what="\"auto\" or a list of sets of 2..4 modes"),
    Key("resonance", "custom", "tolerance on the manifolds' small denominators (relative; default the DPIM's 0.05)",
        check_value=check_resonance, what="a number in [1e-9, 0.5]"),
    Key("ratios", "custom", "per explicit manifold, the resonance vector k ([] : found from the frequencies)",
        check_value=check_ratios, what="a list of lists of positive integers"),
    doc="the DPIM backbone of every master mode",
)


def parse_backbone(file: str | Path | None, table: Any) -> BackboneSpec:
    """The checked ``[analysis.backbone]`` table (a :class:`SceneError` naming the key otherwise)."""
    where = "analysis.backbone"
    got = BACKBONE_KEYS.check(table, file=file, where=where)
    if "amplitudes" in got and "w_over_h" in got:
        raise SceneError(file, f"{where}.w_over_h", "give either amplitudes or w_over_h, not both")
    listed = "amplitudes" if "amplitudes" in got else "w_over_h" if "w_over_h" in got else None
    if listed and isinstance(table, dict) and "points" in table:
        raise SceneError(file, f"{where}.points", f"points sizes the grid drawn without a list; with {listed} the "
                         f"backbone is reported at those values: remove one of the two")
    check_scene_manifolds(file, where, got)
    return BackboneSpec(**got)
