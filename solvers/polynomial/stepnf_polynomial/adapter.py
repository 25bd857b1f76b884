"""Implementation of the ``polynomial`` adapter (see the package docstring).

Loading is defensive: every array's header (``.npy`` headers inside the ``.npz``
zip, dataset metadata in HDF5) is checked for its name, numeric dtype, shape
and size *before* any data is read, and pickled (object) arrays are never
loaded, so a corrupt, crafted or oversized file is a clear error naming the
file and the array.
"""
from __future__ import annotations

import itertools
import math
import zipfile
import zlib
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import scipy.sparse as sp
from numpy.lib import format as npy_format

from stepnf.plugin.adapter import DIRECTIONS, SolverAdapter
from stepnf.errors import SceneError
from stepnf.keys.schema import Key, Schema

REQUIRED = ("M", "K", "G", "H")
OPTIONAL = ("coordinates", "directions", "length")
#: Largest array loaded: 1 GiB is H (n^4 doubles) of a 106-dof system; symmetrising H needs a few
#: times that again, and the polynomial adapter is meant for small reduced systems.
MAX_ARRAY_BYTES = 2**30
#: What a malformed file raises while it is read (zip, zlib, HDF5 and numpy errors).
_READ_ERRORS = (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, RuntimeError,
                NotImplementedError, KeyError, TypeError)


class SystemFileError(ValueError):
    """A polynomial system file is unreadable, or holds arrays of the wrong kind, shape or size."""


def symmetrize(T: np.ndarray) -> np.ndarray:
    """Symmetric part of a tensor in all indices but the first."""
    k = T.ndim - 1
    perms = list(itertools.permutations(range(1, k + 1)))
    return sum(np.transpose(T, (0,) + p) for p in perms) / len(perms)


def expected_shapes(n: int) -> dict[str, tuple[tuple[int, ...], ...]]:
    """Allowed shapes of every array of an ``n``-dof system."""
    return {"M": ((n, n),), "K": ((n, n),), "G": ((n, n, n),), "H": ((n, n, n, n),),
            "coordinates": ((n, 3),), "directions": ((n,),), "length": ((), (1,))}


def check_headers(path: Path, headers: Mapping[str, tuple[tuple[int, ...], np.dtype]]) -> None:
    """Refuse arrays that are not real numbers, too large, or of shapes that do not fit ``M``."""
    for name, (shape, dtype) in headers.items():
        if dtype.hasobject or dtype.kind not in "biuf":
            raise SystemFileError(f"{path}: array {name!r} has dtype {dtype}; a polynomial system holds real "
                                  "numbers (bool, int or float arrays; object/pickled arrays are never loaded)")
        size = math.prod(shape) * dtype.itemsize
        if size > MAX_ARRAY_BYTES:
            raise SystemFileError(f"{path}: array {name!r} announces shape {shape} ({size / 2**30:.3g} GiB); "
                                  f"at most {MAX_ARRAY_BYTES // 2**30} GiB per array is loaded")
    missing = [k for k in REQUIRED if k not in headers]
    if missing:
        raise SystemFileError(f"{path}: missing arrays {missing}; a polynomial system needs {list(REQUIRED)}")
    m_shape = headers["M"][0]
    n = m_shape[0] if len(m_shape) == 2 and m_shape[0] == m_shape[1] and m_shape[0] > 0 else 0
    if not n:
        raise SystemFileError(f"{path}: array 'M' has shape {m_shape}, expected a non-empty square matrix (n, n)")
    for name, shapes in expected_shapes(n).items():
        if name in headers and headers[name][0] not in shapes:
            raise SystemFileError(f"{path}: array {name!r} has shape {headers[name][0]}, expected "
                                  f"{' or '.join(map(str, shapes))} for n = {n} dofs (the size of M)")


def _npy_header(fp) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype of the ``.npy`` stream ``fp``, leaving it at the start of the data."""
    version = npy_format.read_magic(fp)
    if version == (1, 0):
        shape, fortran, dtype = npy_format.read_array_header_1_0(fp)
    elif version == (2, 0):
        shape, fortran, dtype = npy_format.read_array_header_2_0(fp)
    else:
        raise ValueError(f".npy format version {version} is not supported (1.0 and 2.0 are)")
    return tuple(int(d) for d in shape), np.dtype(dtype)


def _load_npz(path: Path) -> dict[str, np.ndarray]:
    """The known arrays of an ``.npz`` file, each header checked before its data is read."""
    with zipfile.ZipFile(path) as z:
        members = {info.filename[:-4]: info for info in z.infolist() if info.filename.endswith(".npy")}
        members = {k: v for k, v in members.items() if k in REQUIRED + OPTIONAL}
        headers = {}
        for name, info in members.items():
            with z.open(info) as fp:
                try:
                    headers[name] = _npy_header(fp)
                except ValueError as exc:
                    raise SystemFileError(f"{path}: array {name!r} is not a readable .npy array: {exc}") from exc
        check_headers(path, headers)
        data = {}
        for name, info in members.items():
            with z.open(info) as fp:
                data[name] = npy_format.read_array(fp, allow_pickle=False)
            if data[name].shape != headers[name][0]:
                raise SystemFileError(f"{path}: array {name!r} is truncated")
    return data


def _load_h5(path: Path) -> dict[str, np.ndarray]:
    """The known datasets of an HDF5 file, their shapes and dtypes checked before reading."""
    import h5py

    with h5py.File(path, "r") as f:
        sets = {k: f[k] for k in REQUIRED + OPTIONAL if k in f and isinstance(f[k], h5py.Dataset)}
        check_headers(path, {k: (tuple(int(d) for d in ds.shape), ds.dtype) for k, ds in sets.items()})
        return {k: np.asarray(ds[()]) for k, ds in sets.items()}


def load_system(path: str | Path) -> dict[str, np.ndarray]:
    """Read the arrays of a polynomial system from ``.npz`` or HDF5.

    Raises :class:`FileNotFoundError` or :class:`SystemFileError` (a ValueError) naming the file
    and the array for anything unusable: not a zip/HDF5 file, truncated, missing or extra-large
    arrays, non-numeric or pickled arrays, shapes that do not fit ``M`` (n, n).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"polynomial system file {path} does not exist or is not a file")
    suffix = path.suffix.lower()
    loaders = {".npz": _load_npz, ".h5": _load_h5, ".hdf5": _load_h5}
    if suffix not in loaders:
        raise SystemFileError(f"{path}: unknown polynomial system format {suffix!r}. Pick one of "
                              f"{list(loaders)}")
    try:
        return loaders[suffix](path)
    except SystemFileError:
        raise
    except _READ_ERRORS as exc:
        kind = "an .npz (zip) archive of .npy arrays" if suffix == ".npz" else "an HDF5 file"
        raise SystemFileError(f"{path}: unreadable, corrupt or truncated; expected {kind} "
                              f"({type(exc).__name__}: {exc})") from exc


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


def _optional_arrays(n: int, coordinates, directions, length, source: str):
    """``coordinates`` (n, 3) finite, ``directions`` (n,) codes into DIRECTIONS, ``length`` > 0 (or None)."""
    X = D = L = None
    if coordinates is not None:
        X = np.asarray(coordinates, dtype=float)
        if X.shape != (n, 3) or not np.all(np.isfinite(X)):
            raise ValueError(f"{source}: array coordinates must be finite with shape {(n, 3)}, got shape {X.shape}")
    if directions is not None:
        d = np.asarray(directions)
        if d.shape != (n,) or d.dtype.kind not in "iub" or np.any((d < 0) | (d >= len(DIRECTIONS))):
            raise ValueError(f"{source}: array directions must hold {n} integer codes in [0, {len(DIRECTIONS) - 1}] "
                             f"(indices into {list(DIRECTIONS)})")
        D = d.astype(int)
    if length is not None:
        a = np.asarray(length, dtype=float)
        if a.size != 1 or not math.isfinite(float(a.ravel()[0])) or not float(a.ravel()[0]) > 0:
            raise ValueError(f"{source}: array length must be one positive finite number, got {a.ravel()[:3]}")
        L = float(a.ravel()[0])
    return X, D, L


class PolynomialAdapter(SolverAdapter):
    """Exact cubic internal force from given tensors; offers the intrusive tensors too."""

    name = "polynomial"
    #: The ``[model]`` keys (``stepnf solvers --keys polynomial``).
    model_keys = Schema(Key("file", "file", "the system: an .npz or HDF5 file with arrays M, K, G, H (and optional "
                            "coordinates, directions, length)", required=True, suffixes=(".npz", ".h5", ".hdf5"),
                            what="an .npz or HDF5 file with arrays M, K, G, H"))
    provides_intrusive_tensors = True
    provides_tangent_stiffness = True

    def __init__(self, M, K, G, H, *, coordinates=None, directions=None, length=None, source: str = "<memory>"):
        M = np.asarray(M, dtype=float)
        K = np.asarray(K, dtype=float)
        if M.ndim != 2 or M.shape[0] != M.shape[1] or not M.shape[0]:
            raise ValueError(f"{source}: array M has shape {M.shape}, expected a non-empty square matrix (n, n)")
        n = M.shape[0]
        shapes = expected_shapes(n)
        for key, arr in (("M", M), ("K", K), ("G", np.asarray(G)), ("H", np.asarray(H))):
            if arr.shape not in shapes[key]:
                raise ValueError(f"{source}: array {key} has shape {arr.shape}, expected {shapes[key][0]}")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{source}: array {key} contains NaN or inf")
        self._M = M
        self._K = K
        self._G = symmetrize(np.asarray(G, dtype=float))
        self._H = symmetrize(np.asarray(H, dtype=float))
        self._X, self._D, self._length = _optional_arrays(n, coordinates, directions, length, source)
        self.source = source

    @classmethod
    def from_config(cls, config: Mapping[str, Any], *, base_dir: Path, scene_file: Path | None = None):
        """Load the system named by ``file`` (:data:`MODEL_KEYS`); an unusable file is a SceneError."""
        path = cls.validate_config(config, base_dir=base_dir, scene_file=scene_file)["file"]
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
