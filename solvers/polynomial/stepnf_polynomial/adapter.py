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

from .matfile import load_mat
from .sparse_tensors import ArrayError, CooTensor, coo_lists

REQUIRED = ("M", "K", "G", "H")
OPTIONAL = ("coordinates", "directions", "length")
#: Each of M, K, G, H may instead be a coordinate list NAME_subs (k, 2 | 3 | 4) and NAME_vals (k,);
#: ``n`` (the number of dofs) is then needed when M is one (docs/adapters.md, :mod:`.sparse_tensors`).
SPARSE_KEYS = tuple(f"{k}_{p}" for k in REQUIRED for p in ("subs", "vals")) + ("n",)
KNOWN = REQUIRED + OPTIONAL + SPARSE_KEYS
#: Number of subscripts per entry of each coordinate list.
ORDERS = {"M": 2, "K": 2, "G": 3, "H": 4}
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
    check_present(path, headers)
    if "M" not in headers:  # M as a coordinate list: n is read with the data (:func:`assemble_system`)
        return
    m_shape = headers["M"][0]
    n = m_shape[0] if len(m_shape) == 2 and m_shape[0] == m_shape[1] and m_shape[0] > 0 else 0
    if not n:
        raise SystemFileError(f"{path}: array 'M' has shape {m_shape}, expected a non-empty square matrix (n, n)")
    for name, shapes in expected_shapes(n).items():
        if name in headers and headers[name][0] not in shapes:
            raise SystemFileError(f"{path}: array {name!r} has shape {headers[name][0]}, expected "
                                  f"{' or '.join(map(str, shapes))} for n = {n} dofs (the size of M)")


def check_present(path: Path, names) -> None:
    """Each of M, K, G, H given once: dense (``G``) or as a coordinate list (``G_subs`` and ``G_vals``)."""
    names = set(names)
    for k in REQUIRED:
        pair = {f"{k}_subs", f"{k}_vals"}
        if k in names and pair & names:
            raise SystemFileError(f"{path}: array {k!r} is given both dense and as {sorted(pair & names)}; "
                                  "give one of the two")
        if k not in names and len(pair & names) == 1:
            raise SystemFileError(f"{path}: missing array {sorted(pair - names)[0]!r} next to "
                                  f"{sorted(pair & names)[0]!r} (a coordinate list needs both)")
    missing = [k for k in REQUIRED if k not in names and f"{k}_subs" not in names]
    if missing:
        raise SystemFileError(f"{path}: missing arrays {missing}; a polynomial system needs {list(REQUIRED)}, "
                              "each dense (key 'G') or as a coordinate list (keys 'G_subs' and 'G_vals')")


def _matrix_of(data: Mapping[str, Any], key: str, n: int, path: Path, base: int):
    """M or K: a dense (n, n) array, a scipy sparse matrix (.mat), or a coordinate list (CSR, duplicates summed)."""
    if key in data:
        A = data[key]
        A = sp.csr_matrix(A, dtype=float) if sp.issparse(A) else np.asarray(A, dtype=float)
        if A.shape != (n, n):
            raise SystemFileError(f"{path}: array {key!r} has shape {A.shape}, expected {(n, n)} "
                                  "(the size of M)")
        return A
    s, v = coo_lists(data[f"{key}_subs"], data[f"{key}_vals"], n, 2, name=key, source=str(path), base=base)
    return sp.csr_matrix((v, (s[:, 0], s[:, 1])), shape=(n, n))


def assemble_system(data: Mapping[str, Any], path: Path, base: int = 0) -> dict[str, Any]:
    """The system of the arrays ``data`` read from ``path``: M, K dense or sparse (CSR), G, H dense or
    :class:`CooTensor`, and the optional arrays. ``base``: 1 for MATLAB's subscripts (.mat), else 0."""
    check_present(path, data)
    if "M" in data:
        n = data["M"].shape[0] if len(data["M"].shape) == 2 else 0
    elif "n" not in data:
        raise SystemFileError(f"{path}: M given as a coordinate list (M_subs, M_vals) needs the array 'n', "
                              "the number of dofs")
    else:
        a = np.asarray(data["n"])
        n = int(a.ravel()[0]) if a.size == 1 and a.dtype.kind in "iuf" and float(a.ravel()[0]).is_integer() else 0
        if n <= 0:
            raise SystemFileError(f"{path}: array 'n' must be one positive integer (the number of dofs), "
                                  f"got {a.ravel()[:3]}")
        # every dof has a mass or a stiffness: fewer entries than dofs is a wrong n (and n-sized arrays
        # built from it would not be bounded by the file's size: n = 1e9 was an out-of-memory kill)
        Kx = data.get("K_vals", data.get("K", ()))
        k = np.asarray(data["M_vals"]).size + (Kx.nnz if sp.issparse(Kx) else np.asarray(Kx).size)
        if n > k:
            raise SystemFileError(f"{path}: array 'n' says {n} dofs but M and K hold {k} entries in all; "
                                  "every dof needs a mass or a stiffness (n is the size of M)")
    if n <= 0:
        raise SystemFileError(f"{path}: array 'M' has shape {data['M'].shape}, expected a non-empty square matrix")
    out: dict[str, Any] = {k: _matrix_of(data, k, n, path, base) for k in ("M", "K")}
    for k in ("G", "H"):
        out[k] = data[k] if k in data else CooTensor.from_lists(*coo_lists(
            data[f"{k}_subs"], data[f"{k}_vals"], n, ORDERS[k], name=k, source=str(path), base=base), n)
    out.update({k: data[k] for k in OPTIONAL if k in data})
    return out


def _load_mat(path: Path) -> dict[str, Any]:
    """A MATLAB .mat file (v7.3 through h5py): 1-based coordinate lists; ``directions`` a row or column of
    (double) codes."""
    data = load_mat(path, KNOWN, MAX_ARRAY_BYTES)
    d = data.get("directions")
    if d is not None and d.ndim == 2 and 1 in d.shape:
        d = d.ravel()
        data["directions"] = d.astype(np.int64) if d.dtype.kind == "f" and np.all(d == np.round(d)) else d
    return assemble_system(data, path, base=1)


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
        members = {k: v for k, v in members.items() if k in KNOWN}
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
    return assemble_system(data, path)


def _load_h5(path: Path) -> dict[str, np.ndarray]:
    """The known datasets of an HDF5 file, their shapes and dtypes checked before reading."""
    import h5py

    with h5py.File(path, "r") as f:
        sets = {k: f[k] for k in KNOWN if k in f and isinstance(f[k], h5py.Dataset)}
        check_headers(path, {k: (tuple(int(d) for d in ds.shape), ds.dtype) for k, ds in sets.items()})
        data = {k: np.asarray(ds[()]) for k, ds in sets.items()}
    return assemble_system(data, path)


def load_system(path: str | Path) -> dict[str, Any]:
    """Read a polynomial system from ``.npz``, HDF5 or MATLAB ``.mat``: M and K dense or sparse (CSR), G and H
    dense or as :class:`CooTensor` (from coordinate lists), and the optional arrays.

    Raises :class:`FileNotFoundError` or :class:`SystemFileError` (a ValueError) naming the file
    and the array for anything unusable: not a zip/HDF5 file, truncated, missing or extra-large
    arrays, non-numeric or pickled arrays, shapes that do not fit ``M`` (n, n).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"polynomial system file {path} does not exist or is not a file")
    suffix = path.suffix.lower()
    loaders = {".npz": _load_npz, ".h5": _load_h5, ".hdf5": _load_h5, ".mat": _load_mat}
    if suffix not in loaders:
        raise SystemFileError(f"{path}: unknown polynomial system format {suffix!r}. Pick one of "
                              f"{list(loaders)}")
    try:
        return loaders[suffix](path)
    except (SystemFileError, ArrayError):  # already naming the file and the array
        raise
    except _READ_ERRORS as exc:
        kind = {".npz": "an .npz (zip) archive of .npy arrays", ".mat": "a MATLAB .mat file"}.get(suffix, "an HDF5 file")
        raise SystemFileError(f"{path}: unreadable, corrupt or truncated; expected {kind} "
                              f"({type(exc).__name__}: {exc})") from exc


def save_system(path: str | Path, M, K, G, H, **extra: Any) -> Path:
    """Write a polynomial system to ``.npz`` (or HDF5 by suffix). M and K may be scipy sparse and G and H
    ``(subs, vals)`` pairs (0-based) or :class:`CooTensor`: each is then written as a coordinate list
    (``M_subs``, ``M_vals``, ... and ``n``)."""
    path = Path(path)
    arrays: dict[str, np.ndarray] = {}
    for k, A in (("M", M), ("K", K), ("G", G), ("H", H)):
        if sp.issparse(A):
            A = sp.coo_matrix(A)
            arrays[f"{k}_subs"], arrays[f"{k}_vals"] = np.stack([A.row, A.col], axis=1).astype(np.int64), A.data
            arrays["n"] = np.asarray(A.shape[0])
        elif isinstance(A, CooTensor):
            arrays[f"{k}_subs"] = np.concatenate([A.rows[:, None], A.lower], axis=1)
            arrays[f"{k}_vals"] = A.vals
        elif isinstance(A, tuple):
            arrays[f"{k}_subs"], arrays[f"{k}_vals"] = np.asarray(A[0], dtype=np.int64), np.asarray(A[1])
        else:
            arrays[k] = np.asarray(A)
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
    model_keys = Schema(Key("file", "file", "the system: an .npz, HDF5 or MATLAB .mat file with arrays M, K, G, H, "
                            "dense or as coordinate lists (G_subs, G_vals, ...), and optional coordinates, "
                            "directions, length", required=True, suffixes=(".npz", ".h5", ".hdf5", ".mat"),
                            what="an .npz, HDF5 or .mat file with arrays M, K, G, H"))
    provides_intrusive_tensors = True
    provides_tangent_stiffness = True

    def __init__(self, M, K, G, H, *, coordinates=None, directions=None, length=None, source: str = "<memory>"):
        """M, K: (n, n) dense or scipy sparse. G, H: dense (n, n, n), (n, n, n, n) (symmetrised, evaluated
        densely as before), or sparse, each a :class:`CooTensor` or a 0-based ``(subs, vals)`` pair: then
        forces cost O(nnz) and no dense tensor is ever built (:mod:`.sparse_tensors`)."""
        self._Gs = self._Hs = None
        if isinstance(G, (tuple, CooTensor)) or isinstance(H, (tuple, CooTensor)):
            self._init_sparse(M, K, G, H, source)
            self._X, self._D, self._length = _optional_arrays(self.n_dofs, coordinates, directions, length, source)
            self.source = source
            return
        M = np.asarray(M.toarray() if sp.issparse(M) else M, dtype=float)
        K = np.asarray(K.toarray() if sp.issparse(K) else K, dtype=float)
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

    def _init_sparse(self, M, K, G, H, source: str) -> None:
        """The sparse path: M, K as CSR, G and H as :class:`CooTensor` (a dense one converted)."""
        mats = []
        for key, A in (("M", M), ("K", K)):
            A = sp.csr_matrix(A, dtype=float)
            if A.shape[0] != A.shape[1] or not A.shape[0] or (mats and A.shape != mats[0].shape):
                raise ValueError(f"{source}: array {key} has shape {A.shape}, expected a non-empty square matrix "
                                 "(n, n) (the size of M)")
            if not np.all(np.isfinite(A.data)):
                raise ValueError(f"{source}: array {key} contains NaN or inf")
            mats.append(A)
        self._M, self._K = mats
        n = self._M.shape[0]
        terms = []
        for key, T in (("G", G), ("H", H)):
            d = ORDERS[key]
            if isinstance(T, tuple):
                T = CooTensor.from_lists(*coo_lists(*T, n, d, name=key, source=source), n)
            elif not isinstance(T, CooTensor):
                T = np.asarray(T, dtype=float)
                if T.shape != (n,) * d or not np.all(np.isfinite(T)):
                    raise ValueError(f"{source}: array {key} must be finite with shape {(n,) * d}, got {T.shape}")
                T = CooTensor.from_dense(T)
            if T.n != n or T.degree != d - 1:
                raise ValueError(f"{source}: tensor {key} is of order {T.degree + 1} for {T.n} dofs, expected "
                                 f"order {d} for n = {n}")
            terms.append(T)
        self._Gs, self._Hs = terms

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
        if self._Gs is not None:
            return (self._K @ U.T).T + self._Gs.forces(U) + self._Hs.forces(U)
        return (U @ self._K.T + np.einsum("ijk,mj,mk->mi", self._G, U, U, optimize=True)
                + np.einsum("ijkl,mj,mk,ml->mi", self._H, U, U, U, optimize=True))

    def tangent_stiffness(self, u):
        """``K + 2 G(u, .) + 3 H(u, u, .)`` (exact; G, H symmetric in their lower indices)."""
        u = self._check_field(u)
        if self._Gs is not None:
            return sp.csr_matrix(self._K + self._Gs.tangent(u) + self._Hs.tangent(u))
        return sp.csr_matrix(self._K + 2 * np.einsum("ijk,j->ik", self._G, u)
                             + 3 * np.einsum("ijkl,j,k->il", self._H, u, u, optimize=True))

    def quadratic_force(self, u, v):
        if self._Gs is not None:
            return self._Gs.polar(np.asarray(u, dtype=float), np.asarray(v, dtype=float))
        return np.einsum("ijk,j,k->i", self._G, u, v)

    def cubic_force(self, u, v, w):
        if self._Hs is not None:
            return self._Hs.polar(*(np.asarray(x, dtype=float) for x in (u, v, w)))
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
        out = {**super().describe(), "file": self.source}
        if self._Gs is not None:
            out["tensors"] = {"format": "sparse", "nnz_G": self._Gs.nnz, "nnz_H": self._Hs.nnz}
        return out
