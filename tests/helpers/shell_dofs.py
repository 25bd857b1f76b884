"""A synthetic model with six dofs per node (ux uy uz rx ry rz), as a shell adapter gives (issue 32, item 1).

Four nodes at the corners of the unit square (z = 0), dofs node-major in the order of
:data:`stepnf.plugin.adapter.DIRECTIONS`. ``M`` is lumped: mass 1 on translations, rotary inertia ``J``
on rotations (radians), so M-normalised modes have rotation entries ``1 / sqrt(J)`` times their share.
``K = M Phi diag(omega^2) Phi^T M`` with ``Phi = M^{-1/2} Q`` (``Q`` orthogonal: a Householder reflection
whose first column is ``q0``): mode 0 is exactly ``phi0 = M^{-1/2} q0`` with

* ``uz = 0.6`` at node 0 (``0.6`` of ``q0``: translational kinetic energy 0.36, all transverse),
* ``rx = 0.8 / sqrt(J) = 8`` rad at node 0 (``J = 0.01``; rotational kinetic energy 0.64),

so its largest entry is a rotation (8 rad per unit modal amplitude) larger than its largest translation
(0.6 model length units). The internal force is an exact cubic in mode 0's coordinate only,
``f(u) = K u + c M phi0 (phi0^T M u)^3``: a Duffing oscillator of frequency 1, so
``T = 3 c / (8 omega^2) = 3 c / 8`` (the DNF of an uncoupled Duffing mode, exact).
The adapter records every field it is sent (``sent``).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from stepnf.plugin.adapter import SolverAdapter
from stepnf.plugin.output_mesh import OutputMesh

NODES = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
N_DOFS = 6 * len(NODES)
#: rotary inertia of each rotation dof (model units: mass x length^2 per radian^2)
J = 0.01
#: the cubic coefficient c of mode 0
C = 0.4
#: analytic T of mode 0 (Duffing, omega = 1): 3 c / 8
T_EXACT = 3 * C / 8
#: thickness h (characteristic length) of the model
H = 0.1
#: mode 0's largest translation (its uz at node 0) and largest rotation (its rx at node 0), exact
W_MAX, ROT_MAX = 0.6, 0.8 / np.sqrt(J)


def mode_basis() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(m, omega, Phi)``: the lumped mass diagonal (n,), frequencies (n,), M-orthonormal modes (n, n)."""
    m = np.tile([1.0, 1.0, 1.0, J, J, J], len(NODES))
    q0 = np.zeros(N_DOFS)
    q0[2], q0[3] = 0.6, 0.8  # uz and rx of node 0
    v = q0 - np.eye(N_DOFS)[0]
    Q = np.eye(N_DOFS) - 2 * np.outer(v, v) / (v @ v)  # Householder: Q e_0 = q0, orthogonal
    omega = 1.0 + 0.37 * np.arange(N_DOFS)  # no 2:1 or 3:1 resonance with mode 0 (1 + 0.37 k is never 2 or 3)
    return m, omega, Q / np.sqrt(m)[:, None]


class SixDofPlate(SolverAdapter):
    """The model of the module docstring (a polynomial-like black box whose dof_directions include rotations)."""

    name = "sixdof"

    def __init__(self):
        self.m, self.omega, self.Phi = mode_basis()
        Mphi = self.m[:, None] * self.Phi
        self.K = Mphi @ np.diag(self.omega ** 2) @ Mphi.T
        self.K = (self.K + self.K.T) / 2
        self.phi0 = self.Phi[:, 0]
        self.sent: list[np.ndarray] = []

    @property
    def n_dofs(self) -> int:
        return N_DOFS

    def mass_matrix(self):
        return sp.diags(self.m).tocsr()

    def stiffness_matrix(self):
        return sp.csr_matrix(self.K)

    def _internal_forces(self, U):
        U = np.asarray(U, dtype=float)
        self.sent.extend(U.copy())  # a copy: a force evaluator may write the forces over U afterwards
        a = U @ (self.m * self.phi0)  # mode 0's coordinate of each field
        return U @ self.K.T + C * np.outer(a ** 3, self.m * self.phi0)

    def dof_coordinates(self):
        return np.repeat(NODES, 6, axis=0)

    def dof_directions(self):
        return np.tile(np.arange(6), len(NODES))

    def characteristic_length(self):
        return H

    def output_mesh(self):
        return OutputMesh(NODES.copy(), [("quad", np.array([[0, 1, 3, 2]]))])


def scene_text(extra: str = "") -> str:
    """A scene of the ``sixdof`` solver: master mode 0, DNF, h = 0.1, transverse uz (``extra``: more lines
    of ``[analysis]``)."""
    return ('[model]\nsolver = "sixdof"\n[analysis]\nmaster_modes = [0]\nmethods = ["dnf"]\n'
            f'thickness = {H}\ntransverse = "uz"\n{extra}[output]\ndir = "out"\n')


def run_six_dof(tmp_path, monkeypatch, extra: str = ""):
    """Run :func:`scene_text` (``extra`` lines in ``[analysis]``) in ``tmp_path`` with the solver ``sixdof``
    resolving to :class:`SixDofPlate`; return the result and the adapter (its ``sent`` fields)."""
    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import load_scene
    from helpers.systems import use_solver

    built: list[SixDofPlate] = []

    class Recorded(SixDofPlate):
        def __init__(self):
            super().__init__()
            built.append(self)

    use_solver(monkeypatch, lambda name: Recorded)
    path = tmp_path / "s.toml"
    path.write_text(scene_text(extra))
    return run_scene(load_scene(path)), built[0]
