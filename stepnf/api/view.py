"""The typed, read-only result of a run, as :func:`stepnf.run` returns it and :func:`stepnf.open` reads it back.

A :class:`RunView` is built from the run's JSON document (``stepnf run --json``: the numbers there are
the numbers here, bit for bit; an infinite T stored as ``"inf"`` is ``float("inf")`` here) and, for a
run just computed, from its :class:`~stepnf.io.results.RunResult` (the DPIM parametrisations behind the
backbone figure live only in memory). Every value is a frozen dataclass, a tuple, a read-only mapping
or a read-only numpy array.

Units are the model's: ``omega`` in rad per model time unit (rad/s for SI models), ``frequency`` =
omega / (2 pi) (Hz for SI models), ``T`` in 1/length^2 for mass-normalised modes (``w_NL = w (1 + T
A^2)``), ``Gamma`` dimensionless, backbone amplitudes ``A`` of the master coordinate ``q_p = phi_p^T M
x`` in model length units.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from stepnf.io.results import RunResult

if TYPE_CHECKING:  # matplotlib and pandas are optional: imported by the methods that draw or tabulate
    import pandas
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


def number(x: Any) -> float | None:
    """A JSON number of the document as a float (``"inf"``/``"-inf"`` included), ``None`` for null."""
    return None if x is None else float(x)


def frozen_array(values: Any) -> np.ndarray:
    """``values`` as a float array that cannot be written to (a JSON null is NaN)."""
    a = np.asarray([np.nan if v is None else float(v) for v in values], dtype=float)
    a.flags.writeable = False
    return a


def label_of(x: Any) -> tuple[int, ...] | str | None:
    """A stored label: ``[k, n]`` -> ``(k, n)``, a string stays, null is None."""
    return tuple(x) if isinstance(x, list) else x


@dataclass(frozen=True)
class MethodView:
    """T of one master mode by one method (:class:`stepnf.nf.coefficient.MethodResult`).

    ``behaviour``: "hardening" (T > 0), "softening" (T < 0), "linear", or "diverges" (infinite T);
    ``na``: ``(kind, reason)`` when the table shows T as n/a (the number is kept), else None.
    """

    name: str
    T: float
    C: tuple[float, ...]
    gamma: float | None
    T_error: float | None
    order: str
    retained_modes: int | None
    flags: tuple[Mapping[str, Any], ...]
    na: tuple[str, str] | None
    behaviour: str

    @property
    def hardening(self) -> bool:
        """``behaviour == "hardening"`` (T > 0 and finite; read :attr:`na` for whether the table trusts it)."""
        return self.behaviour == "hardening"

    @property
    def softening(self) -> bool:
        """``behaviour == "softening"`` (T < 0 and finite)."""
        return self.behaviour == "softening"

    @classmethod
    def of(cls, name: str, d: Mapping[str, Any]) -> "MethodView":
        na = d.get("na")
        return cls(name=name, T=float(d["T"]), C=tuple(float(c) for c in d.get("C", ())), gamma=number(d.get("gamma")),
                   T_error=number(d.get("T_error")), order=d.get("order", "modal"),
                   retained_modes=d.get("retained_modes"), flags=tuple(map(_frozen, d.get("flags") or ())),
                   na=None if na is None else (str(na["kind"]), str(na["reason"])),
                   behaviour=str(d.get("behaviour") or _behaviour(float(d["T"]))))


@dataclass(frozen=True)
class BackboneView:
    """A master mode's DPIM backbone as the run reported it (:mod:`stepnf.dpim.backbone_report`).

    ``amplitude`` (A, model length units), ``omega`` (rad per time unit), ``frequency_ratio``
    (omega / omega_p) and ``w_max_over_h`` are arrays of the same length (NaN where the parametrisation
    does not reach A); ``valid_up_to`` the validity limit in A (None: not reached in the range searched).
    """

    order: int
    amplitude: np.ndarray
    omega: np.ndarray
    frequency_ratio: np.ndarray
    w_max_over_h: np.ndarray | None
    valid_up_to: float | None
    valid_reason: str | None
    flags: tuple[Mapping[str, Any], ...]

    @classmethod
    def of(cls, d: Mapping[str, Any]) -> "BackboneView":
        wh = d.get("w_max_over_h")
        return cls(order=int(d["order"]), amplitude=frozen_array(d.get("amplitude") or ()),
                   omega=frozen_array(d.get("omega") or ()), frequency_ratio=frozen_array(d.get("omega_ratio") or ()),
                   w_max_over_h=None if wh is None else frozen_array(wh), valid_up_to=number(d.get("valid_up_to")),
                   valid_reason=d.get("valid_reason"), flags=tuple(map(_frozen, d.get("flags") or ())))


@dataclass(frozen=True)
class ModeView:
    """One master mode: ``index`` among the elastic modes, ``label``, ``omega``, the slow/fast ratio ``rho``
    (and the mode ``rho_mode`` it is measured against), ``methods`` (name -> :class:`MethodView`, in the
    scene's order), the mode's own ``flags`` and its ``backbone`` (None without ``[analysis.backbone]``); ``frc``: its
    forced responses, one read-only mapping per forcing level as the JSON document's ``frc`` (None without
    ``[analysis.forcing]``; empty when the master has none, ``frc_reason`` says why)."""

    index: int
    label: tuple[int, ...] | str | None
    omega: float
    omega_bar: float | None
    rho: float | None
    rho_mode: int | None
    methods: Mapping[str, MethodView]
    flags: tuple[Mapping[str, Any], ...]
    backbone: BackboneView | None
    frc: tuple[Mapping[str, Any], ...] | None = None
    frc_reason: str | None = None

    @property
    def frequency(self) -> float:
        """omega / (2 pi): Hz for a model in SI units."""
        return self.omega / (2 * math.pi)

    @property
    def T(self) -> Mapping[str, float]:
        """Method -> T."""
        return MappingProxyType({k: m.T for k, m in self.methods.items()})

    @property
    def gamma(self) -> Mapping[str, float | None]:
        """Method -> Gamma (None where the model gives no thickness)."""
        return MappingProxyType({k: m.gamma for k, m in self.methods.items()})

    @classmethod
    def of(cls, d: Mapping[str, Any]) -> "ModeView":
        methods = {k: MethodView.of(k, v) for k, v in (d.get("methods") or {}).items()}
        bb = d.get("backbone")
        return cls(index=int(d["index"]), label=label_of(d.get("label")), omega=float(d["omega"]),
                   omega_bar=number(d.get("omega_bar")), rho=number(d.get("rho")), rho_mode=d.get("rho_mode"),
                   methods=MappingProxyType(methods), flags=tuple(map(_frozen, d.get("flags") or ())),
                   backbone=None if bb is None else BackboneView.of(bb),
                   frc=None if d.get("frc") is None else tuple(map(_frozen, d["frc"])), frc_reason=d.get("frc_reason"))


def _behaviour(T: float) -> str:
    """:attr:`stepnf.nf.coefficient.MethodResult.behaviour` of a document that does not store it."""
    if math.isinf(T):
        return "diverges"
    return "hardening" if T > 0 else ("softening" if T < 0 else "linear")


def _frozen(flag: Mapping[str, Any]) -> Mapping[str, Any]:
    return MappingProxyType(dict(flag))


class RunView:
    """What a run computed, read-only (module docstring). Built by :func:`stepnf.run` and :func:`stepnf.open`."""

    def __init__(self, document: Mapping[str, Any], result: RunResult, *, table: str | None = None):
        self._doc = json.loads(json.dumps(document, allow_nan=False))  # a private copy, as stored
        self._result = result
        self._table = table
        self.modes: tuple[ModeView, ...] = tuple(ModeView.of(m) for m in self._doc.get("modes", ()))

    def __repr__(self) -> str:
        masters = ", ".join(f"{m.index}" for m in self.modes)
        return f"<stepnf run: {self._doc.get('scene', {}).get('solver')}, master modes [{masters}], methods " \
               f"{list(self.methods)}>"

    # ------------------------------------------------------------ numbers
    @property
    def methods(self) -> tuple[str, ...]:
        """The methods computed, in the scene's order."""
        seen: dict[str, None] = {}
        for m in self.modes:
            seen.update(dict.fromkeys(m.methods))
        return tuple(seen)

    def mode(self, index: int) -> ModeView:
        """The master mode of elastic index ``index`` (KeyError naming the master modes otherwise)."""
        for m in self.modes:
            if m.index == index:
                return m
        raise KeyError(f"mode {index} is not a master mode of this run (master modes: {[m.index for m in self.modes]})")

    def T(self, method: str) -> Mapping[int, float]:
        """Master mode index -> T by ``method``."""
        return MappingProxyType({m.index: m.methods[method].T for m in self.modes if method in m.methods})

    def gamma(self, method: str) -> Mapping[int, float | None]:
        """Master mode index -> Gamma by ``method``."""
        return MappingProxyType({m.index: m.methods[method].gamma for m in self.modes if method in m.methods})

    @property
    def flags(self) -> tuple[Mapping[str, Any], ...]:
        """The run's own flags (each mode and method has its own: :attr:`ModeView.flags`, :attr:`MethodView.flags`)."""
        return tuple(map(_frozen, self._doc.get("flags") or ()))

    @property
    def counts(self) -> Mapping[str, int]:
        """Force evaluations, linear solves, factorisations, ..."""
        return MappingProxyType(dict(self._doc.get("counts") or {}))

    @property
    def timings(self) -> Mapping[str, float]:
        """Stage -> wall-clock seconds."""
        return MappingProxyType(dict(self._doc.get("timings") or {}))

    @property
    def kappa(self) -> float | None:
        return number(self._doc.get("kappa"))

    @property
    def spectrum(self) -> Mapping[str, Any]:
        return MappingProxyType(dict(self._doc.get("spectrum") or {}))

    @property
    def hdf5_path(self) -> str | None:
        """The results file (None when nothing was written)."""
        return self._result.hdf5_path

    @property
    def files(self) -> tuple[str, ...]:
        """The other files written (field files, figures)."""
        return tuple(self._result.extra_files)

    @property
    def backbones(self) -> Mapping[int, BackboneView]:
        """Master mode index -> its backbone, for the masters that have one."""
        return MappingProxyType({m.index: m.backbone for m in self.modes if m.backbone is not None})

    def array(self, name: str) -> np.ndarray:
        """A stored array (``phi_masters``, ``dof_coordinates``, ``backbone_<p>_Y``, ...), read-only."""
        a = np.array(self._result.arrays[name])
        a.flags.writeable = False
        return a

    @property
    def array_names(self) -> tuple[str, ...]:
        return tuple(self._result.arrays)

    # ------------------------------------------------------------ documents
    def table(self) -> str:
        """The table ``stepnf run`` prints (and ``stepnf show`` for a stored run)."""
        if self._table is None:
            from stepnf.report.table import format_table

            self._table = format_table(self._result)
        return self._table

    def to_dict(self) -> dict[str, Any]:
        """The JSON document of ``stepnf run --json`` (a fresh copy)."""
        return json.loads(json.dumps(self._doc))

    def to_json(self, indent: int | None = 2) -> str:
        """The text of ``stepnf run --json`` (``indent=None``: ``--compact``)."""
        return json.dumps(self._doc, allow_nan=False, indent=indent)

    def to_dataframe(self) -> "pandas.DataFrame":
        """One row per master mode and method (pandas; :func:`stepnf.api.frame.dataframe`)."""
        from stepnf.api.frame import dataframe

        return dataframe(self)

    # ------------------------------------------------------------ figures
    def plot_backbone(self, mode: int | None = None, ax: "Axes | None" = None) -> "Axes":
        """Draw the backbone of master ``mode`` (default: the first with one) on ``ax`` (a new figure
        if None) and return the axes (:func:`stepnf.api.plots.plot_backbone`)."""
        from stepnf.api.plots import plot_backbone

        return plot_backbone(self, self._result, mode, ax)

    def plot_modes(self) -> "Figure | None":
        """The master mode shapes seen from above (the run's ``NAME_modes.png``), or None for a model
        without dof coordinates (:func:`stepnf.api.plots.plot_modes`)."""
        from stepnf.api.plots import plot_modes

        return plot_modes(self._result)
