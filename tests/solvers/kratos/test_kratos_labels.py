"""Kratos's mode labels are the shared ones of :mod:`stepnf.geometry.labels` (``ModeLabeler.from_dofs`` on
the node translations, ``edge_is_held`` with six dofs per node): the edge counts as a nodal circle exactly
when the fixed dofs hold the normal displacement all along the rim, the solid adapters' convention. On a
flat plate a rim held in uz is held; on a cap (normals tilted out of z) uz alone is not: before, the kratos
adapter counted it (its own check read uz only) and a scene's labels differed from the solid models'."""
from __future__ import annotations

import numpy as np
import pytest

from helpers.required import requires

from stepnf.geometry.labels import ModeLabeler
from stepnf.linalg.modal_analysis import modal_analysis
from stepnf.plugin.boundary import BoundaryCondition

pytestmark = requires("KratosMultiphysics", "stepnf_kratos")

kratos = pytest.importorskip("stepnf_kratos")

A, H = 0.15, 0.003
MATERIAL = {"E": 1.04e11, "nu": 0.3, "rho": 4400.0}


def labels(R: float, dofs: tuple[int, ...]) -> tuple[list, list]:
    """(adapter's labels, labels without the edge circle) of the 6 lowest modes of a coarse DKT cap."""
    mesh = kratos.cap_surface(A, R, "dkt", n_core=8, n_ring=3, core=0.5)
    with kratos.KratosAdapter(mesh, element="dkt", thickness=H, material=MATERIAL,
                              geometry={"a": A, "R": R, "h": H},
                              boundary=[BoundaryCondition("model.boundary[0]", dofs, set="edge")]) as ad:
        Phi = modal_analysis(ad.stiffness_matrix(), ad.mass_matrix(), 6).phi[:, :6]
        plain = ModeLabeler.from_dofs(ad.dof_coordinates(), ad.dof_directions(), A, R)
        return ad.mode_labels(Phi), [plain.label_dofs(p) for p in Phi.T]


def test_the_edge_circle_counts_only_where_the_normal_displacement_is_held():
    got, plain = labels(float("inf"), (2,))  # a plate held in uz: held
    assert got == [(k, n + 1) for k, n in plain]
    got, plain = labels(A ** 2 / (25 * H), (0, 1, 2))  # the kappa = 25 cap, translations held: held
    assert got == [(k, n + 1) for k, n in plain]
    got, plain = labels(A ** 2 / (25 * H), (2,))  # the same cap held in uz only: the rim moves normally
    assert got == plain
