"""Cross-solver regression: CalculiX (C3D20) against FEniCSx (27-node bricks) on the same caps.

Issue 4's acceptance: on the shallow cap of the paper (a = 0.15 m, h = 3 mm,
default mesh), the DNF Gamma of (2,0), (0,1) and (3,0) agree within 2 % at
kappa = 0 and kappa = 25, and the frequencies within 0.5 %. Both models are 3D
St Venant-Kirchhoff solids on the same geometry map; they differ by the
element (serendipity 20-node vs triquadratic 27-node) and by CalculiX's
7-digit force output. Measured here: frequencies within 1e-4, Gamma within 0.6 %.
"""
from __future__ import annotations

import time

import pytest

from helpers.required import requires

pytestmark = [
    pytest.mark.slow, pytest.mark.calculix, pytest.mark.fenicsx,
    requires("ccx"),
]
pytest.importorskip("stepnf_calculix")
pytest.importorskip("stepnf_fenicsx")
pytest.importorskip("dolfinx")

LABELS = [(2, 0), (0, 1), (3, 0)]


def _run(solver: str, element: str, R, tmp_path):
    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import parse_scene

    data = {
        "model": {"solver": solver, "element": element,
                  "geometry": {"shape": "spherical_cap", "a": 0.15, "R": R, "h": 0.003},
                  "material": {"E": 1.04e11, "nu": 0.3, "rho": 4400.0}},
        "analysis": {"master_modes": [f"({k},{n})" for k, n in LABELS], "methods": ["dnf"]},
        "output": {"dir": str(tmp_path / solver)},
    }
    t0 = time.perf_counter()
    res = run_scene(parse_scene(data, base_dir=tmp_path), write=False)
    seconds = time.perf_counter() - t0
    out = {}
    for m in res.modes:
        out[tuple(m.label)] = (m.omega, m.methods["dnf"].gamma)
    return out, seconds


@pytest.mark.parametrize("R, kappa", [("inf", 0), (1.5, 25)])
def test_calculix_matches_fenicsx(tmp_path, R, kappa):
    ccx, t_ccx = _run("calculix", "hex20", R, tmp_path)
    fx, t_fx = _run("fenicsx", "hex27", R, tmp_path)
    print(f"\nkappa = {kappa}: calculix {t_ccx:.1f} s, fenicsx {t_fx:.1f} s")
    for lab in LABELS:
        (w1, g1), (w2, g2) = ccx[lab], fx[lab]
        print(f"  {lab}: omega {w1:.2f} / {w2:.2f}, Gamma {g1:.5f} / {g2:.5f}")
        assert w1 == pytest.approx(w2, rel=5e-3), lab  # issue 4: frequencies within 0.5 %
        assert g1 == pytest.approx(g2, rel=2e-2), lab  # issue 4: Gamma within 2 %
