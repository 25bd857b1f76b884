"""Stage ``output_mesh``: the adapter's mesh for the field files, asked while the adapter is open."""
from __future__ import annotations

import warnings

from ..adapter import adapter_label
from ..errors import OutputWarning
from .state import RunState


def output_mesh_stage(state: RunState) -> None:
    """Ask the adapter for its :meth:`~stepnf.adapter.SolverAdapter.output_mesh` when the run writes fields.

    Reads ``want_fields``, ``adapter``; writes ``output_mesh`` (``None``: no field files, the
    adapter gives no mesh). The field files are an extra: an exception the adapter raises here
    costs them, with one :class:`OutputWarning` naming the adapter, not the computed results.
    """
    if not state.want_fields:
        return
    try:
        state.output_mesh = state.adapter.output_mesh()
    except Exception as exc:  # noqa: BLE001 - any failure of the adapter's own code, said by name
        warnings.warn(f"no field files: {adapter_label(state.adapter)}: output_mesh() raised "
                      f"{type(exc).__name__}: {exc}", OutputWarning, stacklevel=2)
        state.output_mesh = None
