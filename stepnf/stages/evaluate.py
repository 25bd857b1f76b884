"""Stage ``evaluators``: every method of every master mode, with its diagnostics."""
from __future__ import annotations

import numpy as np

from ..diagnostics import overflow_is_numerical
from ..gamma import gamma_scale
from .master import master_data, mode_record
from .methods import run_method
from .state import RunState


def evaluators_stage(state: RunState) -> None:
    """Evaluate the scene's methods for each master mode, in the scene's order.

    Reads ``scene``, ``adapter``, ``X``, ``dirs``, ``basis``, ``labels``, ``masters``, ``methods``,
    ``steps``, ``full``, ``policy``, ``M``. Writes ``scales`` (shell scales, or None), ``gscale`` and
    ``no_gamma`` (how Gamma is scaled, or why it is not), ``modes`` (one
    :class:`~stepnf.results.ModeResult` per master), ``arrays`` (``Gv_<p>`` = G(phi_p, phi_p), empty
    without a targeted STEP) and, when a full-order method runs, ``context``. A floating-point
    overflow becomes a :class:`~stepnf.errors.NumericalError` naming the master and the method.
    """
    state.scales = state.adapter.shell_scales()
    state.gscale, state.no_gamma = gamma_scale(state.scene, state.adapter, state.X, state.dirs)
    where = {"stage": "evaluators"}
    with overflow_is_numerical(where, state.steps), \
            state.progress.stage("evaluators", "normal form and modal derivatives"):
        for p in state.masters:
            where.update(master=int(p), method="(diagnostics)")
            d = master_data(state, p)
            rec = mode_record(state, d)
            for name, ev in state.methods.items():
                where.update(master=int(p), method=name)
                rec.methods[name] = run_method(state, d, name, ev)
            state.modes.append(rec)
            state.arrays[f"Gv_{p}"] = d.st.Gv if d.st is not None else np.zeros(0)
