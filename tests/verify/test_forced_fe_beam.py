"""Issue 34's FE check: a clamped-clamped beam (FEniCSx, tests/helpers/beam.py's steel beam L/h = 100, 20 x 1 x 1
hex27 cells, 1053 free dofs) forced at two modal levels; the ROM's FRC peak (scene keys [analysis.damping],
[analysis.forcing], DPIM order 7) against the full model's steady state by time integration
(stepnf.verify.forced_steady) at the ROM's peak frequency and 1% on either side of it.

Damping: Rayleigh ``C = beta K``, ``beta = 2 xi / w`` with the Euler-Bernoulli estimate ``w = 336.6 rad/s``
(the FE model's 338.5 gives xi = 0.0201 for the master, more for the higher modes, which the integration's
transients then lose quickly). Forcing ``F = k M phi_0``, ``k = 15`` and ``30``: peaks at W_max/h = 0.34 and
0.53, 3% and 7% above w (the beam hardens: folds at the higher level).
"""
from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp

from helpers.beam import L, beam_mesh, beam_scene

pytestmark = [pytest.mark.fenicsx, pytest.mark.slow]

XI, W_EST = 0.02, 336.6
LEVELS = (15.0, 30.0)


def beam_model(folder):
    """The scene's run on its adapter (stepnf.pipeline.run.run_on_adapter): ``(adapter, result, model)``."""
    meshio = pytest.importorskip("meshio")
    from stepnf.pipeline.model import open_model
    from stepnf.pipeline.run import run_on_adapter
    from stepnf.scene.parse import load_scene

    pts, cells = beam_mesh((20, 1, 1))
    meshio.Mesh(pts, [("hexahedron27", cells)]).write(folder / "beam.vtu")
    clamps = [{"box": [[0.0, -1.0, -1.0], [0.0, 1.0, 1.0]]}, {"box": [[L, -1.0, -1.0], [L, 1.0, 1.0]]}]
    extra = (f"[analysis.backbone]\norder = 7\n[analysis.damping]\nrayleigh = [0.0, {2 * XI / W_EST!r}]\n"
             f"[analysis.forcing]\nmodal = {json.dumps(list(LEVELS))}\nfrequency_range = [0.95, 1.3]\n")
    (folder / "beam.toml").write_text(beam_scene("beam.vtu", clamps, methods=("dnf",), analysis=extra))
    scene = load_scene(folder / "beam.toml")
    adapter = open_model(scene)
    result, model = run_on_adapter(scene, adapter)
    return adapter, result, model


def test_rom_peaks_against_full_steady_states(tmp_path):
    """At each level: the full model's steady amplitude at the ROM's peak frequency within the issue's 2% of the
    ROM's peak amplitude (measured 8.8e-4 and 1.3e-3 with 128 steps a period; here 64, whose own error is
    4e-4, tests/verify/test_forced_steady.py), and smaller 0.2% below and above that frequency (by 1.3e-3 to
    2.2e-3 of A at 128 steps): the full model's peak frequency is within 0.2% of the ROM's (the issue's
    floor: 2%; the parabola through the three puts it at 3.6e-4 and 1.4e-4 from the ROM's, docs/forced.md).
    1% away would not do: at k = 30 the ROM's peak is 0.5% below the upper fold, and a run beyond the fold
    is a long transient down to the lower branch, not settled in 30 periods."""
    from stepnf.verify.forced_steady import ForcedIntegration

    adapter, result, model = beam_model(tmp_path)
    try:
        res = result.backbones[0]
        (rec,) = [m for m in result.modes if m.index == 0]
        assert [lev["kappa"] for lev in rec.frc] == list(LEVELS)
        M, K = model.M, model.K
        C = (2 * XI / W_EST) * sp.csc_matrix(K)
        Mphi = np.asarray(M @ res.phi).ravel()
        for lev, w_max_h in zip(rec.frc, (0.34, 0.53)):
            pk = lev["peak"]
            assert pk["w_max_h"] == pytest.approx(w_max_h, abs=0.01)
            x0, v0 = res.displacement(-np.pi / 2, pk["rho"]), res.velocity(-np.pi / 2, pk["rho"])
            amps = []
            for s in (0.0, -0.002, 0.002):  # the side runs start from the steady state at the ROM's peak
                integ = ForcedIntegration(M, C, K, adapter.internal_forces, lev["kappa"] * Mphi)
                run = integ.run(x0, v0, pk["Omega"] * (1 + s), Mphi, periods=30, steps=64)
                assert run.spread < 1e-4 * run.amplitude  # settled (the side differences are 1.3e-3 of A)
                amps.append(run.amplitude)
                if s == 0.0:
                    x0, v0 = run.x, run.v
            assert pk["amplitude"] == pytest.approx(amps[0], rel=0.02), (lev["kappa"], pk, amps)
            assert amps[1] < amps[0] and amps[2] < amps[0], amps
    finally:
        adapter.close()
