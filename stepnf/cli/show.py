"""``stepnf show RESULT.h5``: the table of a stored run, printed again from its JSON document.

The file is the user's input: one that is missing, a folder, not a stepnf run file, damaged or edited
into a malformed document is an :class:`~stepnf.errors.InputFileError` naming it (exit 2, bad input,
as the README's exit codes say of every file given on the command line). The table is printed with
the file's strings escaped (:func:`stepnf.report.table.format_table` passes it through
:func:`stepnf.runtime.printable.printable`): a received file's escape sequences are shown, never obeyed.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from stepnf.io.atomic import reason
from stepnf.nf.coefficient import MethodResult
from stepnf.errors import InputFileError, StoreError
from stepnf.io.results import ModeResult, RunResult, read_hdf5


def _num(x: Any) -> float:
    """A JSON number back to a float (``"inf"``/``"-inf"`` included); stepnf never stores NaN, so a NaN is
    a document edited by hand (a ValueError, reported as a malformed document)."""
    if isinstance(x, bool):
        raise ValueError(f"a boolean ({x}) where a number belongs")
    v = float(x)
    if math.isnan(v):
        raise ValueError("NaN where a number belongs (stepnf never stores NaN)")
    return v


def _float(x: Any) -> float | None:
    """:func:`_num`, or None."""
    return None if x is None else _num(x)


def _backbone(block: Any) -> Any:
    """A stored backbone block, its ``valid_up_to`` checked: stepnf stores null (not reached) or a finite
    number >= 0; anything else (``"inf"``, a negative, a boolean) is a document edited by hand (ValueError)."""
    v = block.get("valid_up_to") if isinstance(block, dict) else None
    if v is not None and (isinstance(v, bool) or not (math.isfinite(_num(v)) and _num(v) >= 0)):
        raise ValueError(f"backbone valid_up_to = {v!r} (stepnf stores null or a finite number >= 0)")
    return block


def _label(x: Any) -> Any:
    return tuple(x) if isinstance(x, list) else x


def result_from_document(doc: dict[str, Any]) -> RunResult:
    """The :class:`RunResult` a run's JSON document describes (what :func:`stepnf.report.table.format_table` needs)."""
    modes = []
    for m in doc.get("modes", []):
        rec = ModeResult(index=int(m["index"]), label=_label(m.get("label")), omega=_num(m["omega"]),
                         rho=_float(m.get("rho")), rho_mode=m.get("rho_mode"), omega_bar=_float(m.get("omega_bar")),
                         w_max=_float(m.get("w_max")), step=dict(m.get("step") or {}),
                         flags=list(m.get("flags") or []), backbone=_backbone(m.get("backbone")),
                         frc=m.get("frc") if isinstance(m.get("frc"), list) else None,
                         frc_reason=m.get("frc_reason") if isinstance(m.get("frc_reason"), str) else None)
        for name, r in (m.get("methods") or {}).items():
            rec.methods[name] = MethodResult(method=name, T=_num(r["T"]), C=tuple(_num(c) for c in r.get("C", ())),
                                             flags=list(r.get("flags") or []), order=r.get("order", "modal"),
                                             retained_modes=r.get("retained_modes"),
                                             T_error=_float(r.get("T_error")), gamma=_float(r.get("gamma")))
        modes.append(rec)
    return RunResult(scene=dict(doc.get("scene") or {}), modes=modes, counts=dict(doc.get("counts") or {}),
                     timings=dict(doc.get("timings") or {}), memory=dict(doc.get("memory") or {}),
                     spectrum=dict(doc.get("spectrum") or {}),
                     model=dict(doc.get("model") or {}), kappa=_float(doc.get("kappa")),
                     flags=list(doc.get("flags") or []), hdf5_path=doc.get("hdf5"),
                     extra_files=list(doc.get("files") or []))


def stored_result(path: str | Path) -> RunResult:
    """The run stored in ``path`` (an :class:`~stepnf.errors.InputFileError` for a file that is not one)."""
    try:
        if not Path(path).is_file():
            raise InputFileError(path, "a folder, not a results file" if Path(path).is_dir() else "no such file")
    except OSError as exc:  # a name the file system cannot look up (too long)
        raise InputFileError(path, f"cannot read it: {reason(exc)}") from exc
    try:
        doc = read_hdf5(path)
    except StoreError as exc:
        raise InputFileError.of(path, exc) from exc
    try:
        result = result_from_document(doc)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise InputFileError(path, f"the stored run document is incomplete or malformed "
                             f"({type(exc).__name__}: {exc})") from exc
    result.hdf5_path = str(path)
    return result


def stored_table(path: str | Path) -> str:
    """The table of the run stored in ``path``, as the run printed it (:func:`stepnf.report.table.format_table`).

    A document edited by hand (a backbone block with a list cut short, a string for a number) is an
    :class:`~stepnf.errors.InputFileError` naming the file (exit 2), not an internal error.
    """
    from stepnf.report.table import format_table

    result = stored_result(path)
    try:
        return format_table(result)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        raise InputFileError(path, f"the stored run document is malformed ({type(exc).__name__}: {exc})") from exc
