"""Implementation of the ``polynomial`` adapter (see the package docstring)."""
from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import scipy.sparse as sp

from stepnf.adapter import SolverAdapter
from stepnf.errors import SceneError

REQUIRED = ("M", "K", "G", "H")
OPTIONAL = ("coordinates", "directions", "length")


def symmetrize(T: np.ndarray) -> np.ndarray:
    """Symmetric part of a tensor in all indices but the first."""
    k = T.ndim - 1
    perms = list(itertools.permutations(range(1, k + 1)))
    return sum(np.transpose(T, (0,) + p) for p in perms) / len(perms)


def load_system(path: str | Path) -> dict[str, np.ndarray]:
    """Read the arrays of a polynomial system from ``.npz`` or HDF5; raise a clear error when one is missing."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"polynomial system file {path} does not exist")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        with np.load(path) as z:
            data = {k: np.asarray(z[k]) for k in z.files}
    elif suffix in (".h5", ".hdf5"):
        import h5py

        with h5py.File(path, "r") as f:
            data = {k: np.asarray(f[k]) for k in f.keys() if isinstance(f[k], h5py.Dataset)}
    else:
        raise ValueError(f"{path}: unknown polynomial system format {suffix!r}. Pick one of ['.npz', '.h5', '.hdf5']")
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise ValueError(f"{path}: missing arrays {missing}; a polynomial system needs {list(REQUIRED)}")
    return data


def save_system(path: str | Path, M, K, G, H, **extra: Any) -> Path:
    """Write a polynomial system to ``.npz`` (or HDF5 by suffix)."""
    path = Path(path)
    arrays = {"M": np.asarray(M), "K": np.asarray(K), "G": np.asarray(G), "H": np.asarray(H)}
    arrays.update({k: np.asarray(v) for k, v in extra.items()})
    if path.suffix.lower() in (".h5", ".hdf5"):
        import h5py

        with h5py.File(path, "w") as f:
            for k, v in arrays.items():
                f[k] = v
    else:
        np.savez(path, **arrays)
    return path


class PolynomialAdapter(SolverAdapter):
    """Exact cubic internal force from given tensors; offers the intrusive tensors too."""

    name = "polynomial"
    provides_intrusive_tensors = True
    provides_tangent_stiffness = True

    def __init__(self, M, K, G, H, *, coordinates=None, directions=None, length=None, source: str = "<memory>"):
        M = np.asarray(M, dtype=float)
        K = np.asarray(K, dtype=float)
        n = M.shape[0]
        shapes = {"M": (n, n), "K": (n, n), "G": (n, n, n), "H": (n, n, n, n)}
        for key, arr in (("M", M), ("K", K), ("G", np.asarray(G)), ("H", np.asarray(H))):
            if arr.shape != shapes[key]:
                raise ValueError(f"{source}: array {key} has shape {arr.shape}, expected {shapes[key]}")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{source}: array {key} contains NaN or inf")
        self._M = M
        self._K = K
        self._G = symmetrize(np.asarray(G, dtype=float))
        self._H = symmetrize(np.asarray(H, dtype=float))
        self._X = None if coordinates is None else np.asarray(coordinates, dtype=float).reshape(n, 3)
        self._D = None if directions is None else np.asarray(directions, dtype=int).reshape(n)
        self._length = None if length is None else float(np.asarray(length))
        self.source = source

    @classmethod
    def from_config(cls, config: Mapping[str, Any], *, base_dir: Path, scene_file: Path | None = None):
        unknown = sorted(set(config) - {"file"})
        if unknown:
            raise SceneError(scene_file, f"model.{unknown[0]}",
                             "unknown key for solver 'polynomial'; allowed keys: ['file']")
        if "file" not in config:
            raise SceneError(scene_file, "model.file", "solver 'polynomial' needs the key 'file' "
                             "(an .npz or HDF5 file with arrays M, K, G, H)")
        path = Path(config["file"])
        if not path.is_absolute():
            path = Path(base_dir) / path
        try:
            data = load_system(path)
            return cls(data["M"], data["K"], data["G"], data["H"],
                       **{k: data[k] for k in OPTIONAL if k in data}, source=str(path))
        except (OSError, ValueError) as exc:
            raise SceneError(scene_file, "model.file", str(exc)) from exc

    @property
    def n_dofs(self) -> int:
        return self._M.shape[0]

    def mass_matrix(self) -> sp.csr_matrix:
        return sp.csr_matrix(self._M)

    def stiffness_matrix(self) -> sp.csr_matrix:
        return sp.csr_matrix(self._K)

    def _internal_forces(self, U: np.ndarray) -> np.ndarray:
        return (U @ self._K.T + np.einsum("ijk,mj,mk->mi", self._G, U, U, optimize=True)
                + np.einsum("ijkl,mj,mk,ml->mi", self._H, U, U, U, optimize=True))

    def tangent_stiffness(self, u):
        """``K + 2 G(u, .) + 3 H(u, u, .)`` (exact; G, H symmetric in their lower indices)."""
        u = self._check_field(u)
        return sp.csr_matrix(self._K + 2 * np.einsum("ijk,j->ik", self._G, u)
                             + 3 * np.einsum("ijkl,j,k->il", self._H, u, u, optimize=True))

    def quadratic_force(self, u, v):
        return np.einsum("ijk,j,k->i", self._G, u, v)

    def cubic_force(self, u, v, w):
        return np.einsum("ijkl,j,k,l->i", self._H, u, v, w)

    def dof_coordinates(self):
        return self._X

    def dof_directions(self):
        return self._D

    def characteristic_length(self):
        if self._length is not None:
            return self._length
        return super().characteristic_length()

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "file": self.source}
