"""Stage ``output_mesh``: what the results take from the adapter at the end of its run, while it is open."""
from __future__ import annotations

import warnings

from stepnf.errors import OutputWarning
from stepnf.pipeline.outputs import AdapterFacts, RunContext, RunModel
from stepnf.plugin.adapter import adapter_label


def output_mesh_stage(ctx: RunContext, model: RunModel) -> AdapterFacts:
    """The adapter's :meth:`~stepnf.plugin.adapter.SolverAdapter.output_mesh` when the run writes fields, then
    its free-dof map and its description (in that order), as :class:`AdapterFacts`.

    The mesh is None without field files, or when the adapter gives none. The field files are an extra:
    an exception the adapter raises in ``output_mesh()`` costs them, with one :class:`OutputWarning`
    naming the adapter, not the computed results.
    """
    adapter, mesh = model.adapter, None
    if ctx.want_fields:
        try:
            mesh = adapter.output_mesh()
        except Exception as exc:  # noqa: BLE001 - any failure of the adapter's own code, said by name
            warnings.warn(f"no field files: {adapter_label(adapter)}: output_mesh() raised "
                          f"{type(exc).__name__}: {exc}", OutputWarning, stacklevel=2)
            mesh = None
    return AdapterFacts(mesh, adapter.free_dof_map(), adapter.describe())
