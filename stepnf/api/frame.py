"""A run as a pandas DataFrame: one row per master mode and method (pandas is optional).

Columns: ``mode`` (elastic index), ``label`` (text, "(2,0)" or "-"), ``omega`` (rad per time unit),
``frequency`` (omega / 2 pi), ``omega_bar``, ``rho``, ``method``, ``order`` ("modal" | "full"), ``T``,
``gamma``, ``T_error``, ``behaviour``, ``na`` (why the table shows T as n/a, or None) and ``flags``
(the kinds of the method's and mode's flags, comma-separated). The numbers are the JSON document's,
unchanged (a missing one is NaN).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from stepnf.io.results import label_text

if TYPE_CHECKING:
    import pandas


COLUMNS = ("mode", "label", "omega", "frequency", "omega_bar", "rho", "method", "order", "T", "gamma", "T_error",
           "behaviour", "na", "flags")
#: What to install when pandas is missing (the notebook and to_dataframe need it; nothing else does).
INSTALL = ("RunView.to_dataframe needs pandas, which is not installed: install the Debian package python3-pandas "
           "(apt install python3-pandas) or the optional dependency group: pip install 'stepnf[dataframe]'")


def _nan(x: float | None) -> float:
    return float("nan") if x is None else x


def rows(view: Any) -> list[dict[str, Any]]:
    """The rows of :func:`dataframe` of a :class:`~stepnf.api.view.RunView`, as plain dicts (no pandas needed)."""
    out = []
    for m in view.modes:
        for name, r in m.methods.items():
            kinds = sorted({str(f.get("kind")) for f in (*r.flags, *m.flags)})
            out.append({"mode": m.index, "label": label_text(m.label), "omega": m.omega, "frequency": m.frequency,
                        "omega_bar": _nan(m.omega_bar), "rho": _nan(m.rho), "method": name, "order": r.order,
                        "T": r.T, "gamma": _nan(r.gamma), "T_error": _nan(r.T_error), "behaviour": r.behaviour,
                        "na": None if r.na is None else r.na[0], "flags": ", ".join(kinds)})
    return out


def dataframe(view: Any) -> "pandas.DataFrame":
    """The DataFrame of ``view`` (module docstring); ImportError naming the package when pandas is missing."""
    try:
        import pandas
    except ImportError as exc:
        raise ImportError(INSTALL) from exc
    return pandas.DataFrame(rows(view), columns=list(COLUMNS))
