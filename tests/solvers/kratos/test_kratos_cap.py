"""The paper's kappa = 25 cap with its DKT shell model (``examples/shell_kappa25_dkt.toml``: Kratos's
``ShellThinElementCorotational3D3N``, the generated cap's default mid-surface mesh, 11 766 dofs, the
paper's ~12k) at h = 1, 3 and 5 mm against the 3D solid: Gamma of (2,0), (0,1) and (3,0) within 5%, or
0.005 absolute for the small (2,0) (issue 32's bound).

The 3D values (FEniCSx hex27, DNF, the generated cap's default 17 649-dof mesh, the base scene
``examples/table2_base.toml``): h = 3 mm (R = 1.5 m) and h = 5 mm (R = 0.9 m) from the Fig. 4 sweep
store ``docs/fig4/table2.h5`` (cases ``R=1.5_h=0.003``, ``R=0.9_h=0.005``); h = 1 mm (R = 4.5 m, not
a Table 2 case) from ``bench/results/shell_dkt.json`` (run ``3d R=4.5_h=0.001 17.6k``).
``tests/report/test_fig4_dkt.py`` checks these numbers against the store and the JSON.

Measured (one thread, ~6 s per thickness), DKT against 3D for (2,0), (3,0), (0,1): h = 1 mm -0.4%, +0.5%,
+0.3%; h = 3 mm -0.7%, -0.5%, 0.0%; h = 5 mm -1.4%, -1.7%, -0.3% (bench/results/shell_dkt.json; the
DKT mesh is converged to 1.1% for these three modes at kappa = 25: bench/shell_dkt.py).
"""
from __future__ import annotations

import tomllib

import pytest

from helpers.paths import EXAMPLES
from helpers.required import requires

from stepnf.pipeline.run import run_scene
from stepnf.scene.parse import parse_scene

pytestmark = [requires("KratosMultiphysics", "stepnf_kratos"), pytest.mark.slow]  # ~22 s: three cap runs

SCENE = EXAMPLES / "shell_kappa25_dkt.toml"
#: h (m): R (m) giving kappa = a^4 / (R h)^2 = 25 with a = 0.15 m, and the 3D solid's Gamma (see above)
SOLID_3D = {
    0.001: (4.5, {(2, 0): 0.0144593, (0, 1): -0.2315525, (3, 0): 0.1732561}),
    0.003: (1.5, {(2, 0): 0.0139951, (0, 1): -0.2315230, (3, 0): 0.1747630}),
    0.005: (0.9, {(2, 0): 0.0130494, (0, 1): -0.2309941, (3, 0): 0.1765922}),
}


def dkt_gamma(h: float, R: float) -> tuple[float, dict]:
    """kappa and the DNF Gamma of the three modes of the example scene at thickness ``h`` and radius ``R``."""
    data = tomllib.loads(SCENE.read_text())
    assert data["model"]["solver"] == "kratos" and data["model"]["element"] == "dkt"
    data["model"]["geometry"].update({"R": R, "h": h})
    data["analysis"].update({"master_modes": ["(2,0)", "(0,1)", "(3,0)"], "methods": ["dnf"]})
    data["output"] = {"hdf5": False}
    res = run_scene(parse_scene(data, file=SCENE, base_dir=EXAMPLES), write=False)
    return res.kappa, {tuple(m.label): m.methods["dnf"].gamma for m in res.modes}


@pytest.mark.parametrize("h", sorted(SOLID_3D))
def test_kappa25_dkt_against_3d(h):
    R, solid = SOLID_3D[h]
    kappa, dkt = dkt_gamma(h, R)
    assert kappa == pytest.approx(25.0, rel=1e-12)
    for lab, g3d in solid.items():
        if lab == (2, 0):  # Gamma ~ 0.014: the bound for the small (2,0) is 0.005 absolute
            assert dkt[lab] == pytest.approx(g3d, abs=0.005), (h, lab, dkt[lab])
        else:
            assert dkt[lab] == pytest.approx(g3d, rel=0.05), (h, lab, dkt[lab])
