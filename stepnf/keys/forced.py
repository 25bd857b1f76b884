"""The scene tables ``[analysis.damping]`` and ``[analysis.forcing]``: the forced responses of the masters (issue 34).

::

    [analysis.damping]
    rayleigh = [alpha, beta]        # C = alpha M + beta K (alpha 1/time, beta time; >= 0, not both 0)
    # modal = 0.01                  # or the damping ratio of each master: a number, or one per master mode

    [analysis.forcing]
    modal = [k1, k2, k3]            # F = k M phi_p cos(Omega t): one frequency-response curve per level
    # load = {set = "TIP", dofs = ["uz"], amplitude = [10.0, 20.0]}   # or nodal forces (box = ... instead of set)
    frequency_range = [0.9, 1.25]   # Omega / omega_p; must contain 1 (the resonance)
    points = 400                    # optional: samples of each curve

Declared as :class:`stepnf.keys.schema.Schema` s, so a misspelt key, a wrong type or a value out of range is
a :class:`~stepnf.errors.SceneError` naming the key when the scene is read (exit 2); so are the checks
across keys (both or neither of ``rayleigh`` and ``modal``, a ``modal`` list not as long as
``master_modes``, a load on both a set and a box) and across tables (:func:`check_forced_scene`: forcing
without damping has an unbounded peak, forcing without ``[analysis.backbone]`` has no manifold to live on).
Whether the named set exists, and whether the nodes have the named dofs, is decided by the mesh, in the
forced-response stage (:mod:`stepnf.pipeline.forced`). The functions return the checked values as plain
dicts; :mod:`stepnf.scene.parse` builds :mod:`stepnf.forced.spec`'s dataclasses from them.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from stepnf.errors import SceneError
from stepnf.keys.checks import check_number, check_table, describe_value
from stepnf.keys.schema import Key, Schema

#: Rayleigh coefficients: alpha (1/time) and beta (time) in model units, >= 0; 1e15 bounds any unit system.
RAYLEIGH_RANGE = (0.0, 1e15)
#: A damping ratio: > 0 (an undamped peak is unbounded) and < 1 (an overdamped mode has no resonance).
RATIO_RANGE = (0.0, 1.0)
#: Forcing levels (modal force k, or a nodal force amplitude): nonzero, |value| <= 1e15 (force units); at
#: most this many levels (each a curve of ``points`` samples).
LEVEL_LIMIT = 1e15
MAX_LEVELS = 100
#: Omega / omega_p: the range must contain 1 (the resonance); above 10 x omega_p the first-order averaging of
#: the primary resonance says nothing (superharmonic resonances are another computation).
FREQUENCY_RANGE = (0.0, 10.0)
#: Samples of each curve: 20 resolve a peak and two folds coarsely; 100 000 is far beyond any plot.
POINTS_RANGE = (20, 100_000)
DEFAULT_POINTS = 400
#: Coordinates of a box corner: lengths in model units, as the boundary keys allow.
COORDINATE_LIMIT = 1e12


def _rayleigh(file: Any, key: str, value: Any) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2:
        raise SceneError(file, key, "expected [alpha, beta] (C = alpha M + beta K; alpha 1/time, beta time, model "
                         f"units), got {describe_value(value)}")
    lo, hi = RAYLEIGH_RANGE
    a, b = (float(check_number(file, f"{key}[{i}]", v, lo=lo, hi=hi, why=" (a Rayleigh coefficient, >= 0)"))
            for i, v in enumerate(value))
    if a == 0 and b == 0:
        raise SceneError(file, key, "alpha and beta are both 0: no damping (an undamped forced response has an "
                         "unbounded peak); give alpha > 0 or beta > 0")
    return a, b


def _ratio(file: Any, key: str, value: Any) -> float:
    lo, hi = RATIO_RANGE
    return float(check_number(file, key, value, lo=lo, hi=hi, lo_open=True, hi_open=True,
                              why=" (a damping ratio xi: > 0, and < 1 for a resonance)"))


def _modal_damping(file: Any, key: str, value: Any) -> float | tuple[float, ...]:
    if isinstance(value, list):
        if not value:
            raise SceneError(file, key, "expected a damping ratio, or a non-empty list of one per master mode")
        return tuple(_ratio(file, f"{key}[{i}]", v) for i, v in enumerate(value))
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(file, key, f"expected a damping ratio xi in (0, 1) or a list of one per master mode, got "
                         f"{describe_value(value)}")
    return _ratio(file, key, value)


DAMPING_KEYS = Schema(
    Key("rayleigh", "custom", "[alpha, beta]: C = alpha M + beta K (model units)", check_value=_rayleigh,
        what="[alpha, beta], both >= 0, not both 0"),
    Key("modal", "custom", "damping ratio xi of each master (one number, or one per master mode)",
        check_value=_modal_damping, what="a number in (0, 1) or a list of them"),
    doc="the damping of the forced responses",
)


def _levels(file: Any, key: str, value: Any) -> tuple[float, ...]:
    if not isinstance(value, list) or not value or len(value) > MAX_LEVELS:
        raise SceneError(file, key, f"expected a non-empty list (at most {MAX_LEVELS}) of forcing levels, got "
                         f"{describe_value(value)}")
    out = tuple(float(check_number(file, f"{key}[{i}]", v, lo=-LEVEL_LIMIT, hi=LEVEL_LIMIT,
                                   why=" (a force level, model units)")) for i, v in enumerate(value))
    for i, v in enumerate(out):
        if v == 0:
            raise SceneError(file, f"{key}[{i}]", "a forcing level of 0 has no forced response: give a nonzero level")
    if len(set(out)) != len(out):
        raise SceneError(file, key, f"repeated forcing levels in {list(out)}")
    return out


def _range(file: Any, key: str, value: Any) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2:
        raise SceneError(file, key, f"expected [lo, hi] of Omega / omega_p (containing 1, the resonance), got "
                         f"{describe_value(value)}")
    lo, hi = (float(check_number(file, f"{key}[{i}]", v, lo=FREQUENCY_RANGE[0], hi=FREQUENCY_RANGE[1],
                                 lo_open=True, why=" (Omega / omega_p)")) for i, v in enumerate(value))
    if not lo < hi:
        raise SceneError(file, key, f"lo must be below hi, got [{lo:g}, {hi:g}]")
    if not lo < 1 < hi:
        raise SceneError(file, key, f"[{lo:g}, {hi:g}] does not contain the resonance Omega / omega_p = 1: the "
                         "curve would miss its peak and folds; widen it, e.g. [0.8, 1.2]")
    return lo, hi


def _box(file: Any, key: str, value: Any) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``[[x0, y0, z0], [x1, y1, z1]]``: two finite corners, the first the lower one (as the boundary keys)."""
    ok = isinstance(value, list) and len(value) == 2 and all(isinstance(c, list) and len(c) == 3 for c in value)
    if not ok:
        raise SceneError(file, key, "expected two corners [[x0, y0, z0], [x1, y1, z1]] (model length units), got "
                         f"{describe_value(value)}")
    lo, hi = (tuple(float(check_number(file, f"{key}[{i}][{j}]", c, lo=-COORDINATE_LIMIT, hi=COORDINATE_LIMIT))
                    for j, c in enumerate(corner)) for i, corner in enumerate(value))
    bad = [j for j in range(3) if lo[j] > hi[j]]
    if bad:
        raise SceneError(file, key, f"the first corner must be the lower one: coordinate {'xyz'[bad[0]]} has "
                         f"{lo[bad[0]]:g} > {hi[bad[0]]:g}")
    return lo, hi


def load_schema(dof_names: Sequence[str]) -> Schema:
    """The keys of ``load = {...}``: ``set`` or ``box`` (as ``[[model.boundary]]``), ``dofs`` among
    ``dof_names`` (:data:`stepnf.plugin.adapter.DIRECTIONS`), ``amplitude`` (the levels)."""
    return Schema(
        Key("set", "text", "a named node set of the mesh", what="a set name"),
        Key("box", "custom", "the nodes inside the box [[x0, y0, z0], [x1, y1, z1]] (instead of a set)",
            check_value=_box, what="[[x0, y0, z0], [x1, y1, z1]]"),
        Key("dofs", "list", "the loaded dofs of each node (the force acts along each)", required=True,
            choices=tuple(dof_names)),
        Key("amplitude", "custom", "the force on each loaded dof, one forcing level per value (force units)",
            required=True, check_value=_levels, what="a list of nonzero numbers"),
    )


def forcing_schema(dof_names: Sequence[str]) -> Schema:
    """The keys of ``[analysis.forcing]`` (module docstring)."""
    return Schema(
        Key("modal", "custom", "levels k of F = k M phi_p cos(Omega t) (model units)", check_value=_levels,
            what="a list of nonzero numbers"),
        Key("load", "table", "nodal forces {set or box, dofs, amplitude}", table=load_schema(dof_names)),
        Key("frequency_range", "custom", "[lo, hi] of Omega / omega_p, containing 1", required=True,
            check_value=_range, what="[lo, hi] with 0 < lo < 1 < hi <= 10"),
        Key("points", "integer", "samples of each curve", default=DEFAULT_POINTS, lo=POINTS_RANGE[0],
            hi=POINTS_RANGE[1]),
        doc="the harmonic forcing of the forced responses",
    )


def parse_damping(file: str | Path | None, table: Any, n_masters: int) -> dict[str, Any]:
    """The checked ``[analysis.damping]`` (``rayleigh`` or ``modal``, the other None); a :class:`SceneError`
    naming the key otherwise. ``n_masters``: the length of ``master_modes`` (a ``modal`` list's length)."""
    where = "analysis.damping"
    got = DAMPING_KEYS.check(table, file=file, where=where)
    if ("rayleigh" in got) == ("modal" in got):
        raise SceneError(file, where, "give exactly one of rayleigh = [alpha, beta] or modal = xi (a damping ratio, "
                         "or one per master mode)" + (", not both" if got else ""))
    modal = got.get("modal")
    if isinstance(modal, tuple) and len(modal) != n_masters:
        raise SceneError(file, f"{where}.modal", f"one damping ratio per master mode: {n_masters} master mode(s), "
                         f"{len(modal)} ratio(s) (or one number for all)")
    return {"rayleigh": got.get("rayleigh"), "modal": modal}


def parse_forcing(file: str | Path | None, table: Any, dof_names: Sequence[str]) -> dict[str, Any]:
    """The checked ``[analysis.forcing]``: ``modal`` (levels) or ``load`` (a dict of ``set``, ``box``, ``dofs``,
    ``amplitude``), ``frequency_range``, ``points``; a :class:`SceneError` naming the key otherwise."""
    where = "analysis.forcing"
    got = forcing_schema(dof_names).check(table, file=file, where=where)
    if ("modal" in got) == ("load" in got):
        raise SceneError(file, where, "give exactly one of modal = [k1, k2, ...] (levels of F = k M phi_p) or "
                         "load = {set = \"<name>\", dofs = [...], amplitude = [...]}" + (", not both" if
                                                                                          "modal" in got else ""))
    load = got.get("load")
    if load is not None:
        if ("set" in load) == ("box" in load):
            raise SceneError(file, f"{where}.load", "give exactly one of set = \"<name>\" or box = [[x0, y0, z0], "
                             "[x1, y1, z1]] (the loaded nodes)")
        load = {"set": load.get("set"), "box": load.get("box"), "dofs": tuple(load["dofs"]),
                "amplitude": load["amplitude"]}
    return {"modal": got.get("modal"), "load": load, "frequency_range": got["frequency_range"],
            "points": got.get("points", DEFAULT_POINTS)}


def check_forced_scene(file: str | Path | None, analysis: Any, has_backbone: bool) -> None:
    """Checks across the tables of ``[analysis]`` (a mapping): forcing needs damping (else its peak is
    unbounded) and the backbone's manifold; damping alone computes nothing."""
    damping, forcing = "damping" in analysis, "forcing" in analysis
    if forcing:
        check_table(file, "analysis.forcing", analysis["forcing"])
    if forcing and not damping:
        raise SceneError(file, "analysis.forcing", "forcing without [analysis.damping]: an undamped forced response "
                         "has an unbounded peak; add [analysis.damping] (rayleigh = [alpha, beta] or modal = xi)")
    if forcing and not has_backbone:
        raise SceneError(file, "analysis.forcing", "the forced response lives on the backbone's manifold: add "
                         "[analysis.backbone] (order = 7, say)")
    if damping and not forcing:
        raise SceneError(file, "analysis.damping", "damping is used by the forced responses only: add "
                         "[analysis.forcing] (modal = [k], frequency_range = [lo, hi]) or remove [analysis.damping]")


__all__ = ["DAMPING_KEYS", "load_schema", "forcing_schema", "parse_damping", "parse_forcing", "check_forced_scene"]
