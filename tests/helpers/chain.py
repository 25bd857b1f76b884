"""A chain of masses with cubic ground springs: a small conservative adapter for the harness and CLI tests."""
import numpy as np
import scipy.sparse as sp

from stepnf.keys.schema import Key, Schema
from stepnf.plugin.adapter import SolverAdapter

N = 8  # masses, by default


class DuffingChain(SolverAdapter):
    """Masses on a line, each grounded by a spring k0 u + c0 u^3 and coupled to its neighbours by linear
    springs: f is the gradient of an energy (conservative). Length 1, so the harness's fields are ~0.1."""

    model_keys = Schema(Key("n", "integer", "number of masses", default=N, lo=2),
                        Key("c0", "number", "cubic ground stiffness", default=1.0, lo=0))

    def __init__(self, n: int = N, c0: float = 1.0):
        self.n, self.c0 = n, c0
        main = np.full(n, 2.0 + 1.0)
        self.K = sp.diags([main, -np.ones(n - 1), -np.ones(n - 1)], [0, 1, -1], format="csr")

    @property
    def n_dofs(self):
        return self.n

    def mass_matrix(self):
        return sp.identity(self.n, format="csr")

    def stiffness_matrix(self):
        return self.K

    def _internal_force(self, u):
        return self.K @ u + self.c0 * u**3

    def dof_coordinates(self):
        return np.column_stack([np.arange(self.n, dtype=float), np.zeros(self.n), np.zeros(self.n)])

    def dof_directions(self):
        return np.ones(self.n, dtype=int)  # uy: transverse

    def characteristic_length(self):
        return 1.0

    def transverse_displacements(self, Phi):
        return np.asarray(Phi, dtype=float)  # every dof is a transverse (uy) displacement

    def transverse_amplitude(self, phi):
        return float(np.max(np.abs(phi)))
