"""Frequencies of Kratos's thin shells (kratos adapter) against plate theory.

* Clamped square plate (side 1 m, h = 10 mm, steel, nu = 0.3): frequency parameters
  ``lambda = omega a^2 sqrt(rho h / D)`` of Leissa, "The free vibration of rectangular plates", J. Sound
  Vib. 31(3) (1973) 257-293, case C-C-C-C at a/b = 1 (36-term Ritz, Kirchhoff theory): 35.992, 73.413,
  73.413, 108.27. Measured here at 32 x 32 (5 766 free dofs): DKQ +0.026, +0.226, +0.226, +0.202 %;
  DKT +0.065, +0.166, +0.366, +0.339 % (the diagonals split the degenerate pair); 0.5 % is the issue's
  bound, and the errors fall as O(h^2) (measured: 16 x 16 errs ~4x more, 24 x 24 ~1.8x more).
* Free circular plate (a = 0.15 m, h = 3 mm, the paper's material): w_bar of (2,0), (0,1), (3,0) against
  Kirchhoff's (:class:`stepnf.models.vonkarman.VonKarmanShell` at kappa = 0: 5.358, 9.003, 12.439) at
  the default mesh (the solid caps' O-grid n_core = 14, n_ring = 5: 11 766 dofs, the paper's ~12k):
  measured +0.07, +0.05, +0.15 % (DKT) and +0.06, +0.04, +0.14 % (DKQ); the issue's bound is 1 %.
"""
from __future__ import annotations

import numpy as np
import pytest

from helpers.required import requires
from helpers.shells import square_plate

from stepnf.linalg.modal_analysis import modal_analysis
from stepnf.plugin.boundary import BoundaryCondition

pytestmark = requires("KratosMultiphysics", "stepnf_kratos")

kratos = pytest.importorskip("stepnf_kratos")
KratosAdapter, ShellMesh, cap_surface = kratos.KratosAdapter, kratos.ShellMesh, kratos.cap_surface

LEISSA_CCCC = np.array([35.992, 73.413, 73.413, 108.27])


@pytest.mark.parametrize("element", ["dkt", "dkq"])
def test_clamped_square_plate_matches_leissa(element):
    E, nu, rho, h = 2.1e11, 0.3, 7800.0, 0.01
    clamp = BoundaryCondition("model.boundary[0]", (0, 1, 2, 3, 4, 5), set="edge")
    with KratosAdapter(square_plate(32, element), element=element, thickness=h, material={"E": E, "nu": nu, "rho": rho},
                       boundary=[clamp]) as ad:
        basis = modal_analysis(ad.stiffness_matrix(), ad.mass_matrix(), 4)
    lam = basis.omega[:4] * np.sqrt(rho * h / (E * h**3 / (12 * (1 - nu**2))))
    assert np.all(np.abs(lam / LEISSA_CCCC - 1) < 5e-3), lam


@pytest.mark.parametrize("element", ["dkt", "dkq"])
def test_free_circular_plate_matches_kirchhoff(element):
    from stepnf.models.vonkarman import VonKarmanShell

    vk = VonKarmanShell(kappa=0.0, nu=0.3)
    kirchhoff = dict(zip(vk.labels(), vk.omegas()))
    mesh = cap_surface(0.15, float("inf"), element, n_core=14, n_ring=5, core=0.5)
    with KratosAdapter(mesh, element=element, thickness=0.003, material={"E": 1.04e11, "nu": 0.3, "rho": 4400.0},
                       geometry={"a": 0.15, "R": float("inf"), "h": 0.003}) as ad:
        assert ad.n_dofs == 11_766
        basis = modal_analysis(ad.stiffness_matrix(), ad.mass_matrix(), 8)
        assert basis.rigid.shape[1] == 6
        labels = ad.mode_labels(basis.phi[:, :8])
        scales = ad.shell_scales()
    w_bar = {}
    for label, omega in zip(labels, basis.omega[:8]):
        w_bar.setdefault(label, scales.omega_bar(omega))
    for mode in [(2, 0), (0, 1), (3, 0)]:
        assert abs(w_bar[mode] / kirchhoff[mode] - 1) < 1e-2, (mode, w_bar[mode], kirchhoff[mode])
