"""MATLAB ``.mat`` files of a polynomial system: v4-v7 through :func:`scipy.io.loadmat`, v7.3 (an HDF5
file with a 512-byte MATLAB header) through h5py.

Only plain numeric variables are read: dense matrices and MATLAB sparse matrices (``M``, ``K``), the
coordinate lists (``G_subs`` ...; MATLAB's 1-based subscripts, converted by the caller). A Tensor Toolbox
``sptensor``, a cell or a struct is refused with a message saying what to export instead
(``G.subs`` and ``G.vals``, docs/adapters.md). Every variable's size is checked before its data is read.
In v7.3 files MATLAB stores an array column-major, so a (k, 3) array is an HDF5 dataset (3, k): it is
transposed back; a sparse matrix is a group with datasets ``data``, ``ir`` (0-based row of each value),
``jc`` (column pointers) and the attribute ``MATLAB_sparse`` (the number of rows).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
import scipy.sparse as sp

from .sparse_tensors import ArrayError

#: What a MATLAB object or cell needs instead.
EXPORT_HINT = ("export plain arrays: G_subs = fnl{1}.subs; G_vals = fnl{1}.vals (likewise H), "
               "not the sptensor or cell itself (docs/adapters.md)")


def _check_size(path: Path, name: str, shape: tuple[int, ...], itemsize: int, limit: int) -> None:
    size = math.prod(shape) * itemsize
    if size > limit:
        raise ArrayError(f"{path}: array {name!r} announces shape {shape} ({size / 2**30:.3g} GiB); "
                         f"at most {limit // 2**30} GiB per array is loaded")


def _load_v5(path: Path, names: Iterable[str], limit: int) -> dict:
    import scipy.io

    wanted = set(names)
    found = {name: (shape, cls) for name, shape, cls in scipy.io.whosmat(str(path)) if name in wanted}
    for name, (shape, cls) in found.items():
        if cls not in ("double", "single", "sparse", "int8", "int16", "int32", "int64", "uint8", "uint16",
                       "uint32", "uint64", "logical"):
            raise ArrayError(f"{path}: variable {name!r} is a MATLAB {cls}; {EXPORT_HINT}")
        if cls != "sparse":  # a sparse matrix holds O(nnz), not rows x columns (a 12k-dof M was refused)
            _check_size(path, name, tuple(shape), 8, limit)
    if not found:
        return {}
    raw = scipy.io.loadmat(str(path), variable_names=list(found), squeeze_me=False)
    out = {}
    for name in found:
        v = raw[name]
        if sp.issparse(v):
            out[name] = sp.csc_matrix(v)
        elif isinstance(v, np.ndarray) and v.dtype.kind in "biuf":
            out[name] = v
        else:
            raise ArrayError(f"{path}: variable {name!r} holds {v.dtype if isinstance(v, np.ndarray) else type(v)}"
                             f", not real numbers; {EXPORT_HINT}")
    return out


def _load_v73(path: Path, names: Iterable[str], limit: int) -> dict:
    import h5py

    out = {}
    with h5py.File(path, "r") as f:
        for name in names:
            if name not in f:
                continue
            obj = f[name]
            cls = obj.attrs.get("MATLAB_class", b"")
            cls = cls.decode() if isinstance(cls, bytes) else str(cls)
            if isinstance(obj, h5py.Group) and "MATLAB_sparse" in obj.attrs:
                rows = int(obj.attrs["MATLAB_sparse"])
                jc = np.asarray(obj["jc"][()], dtype=np.int64)
                nnz = int(jc[-1]) if len(jc) else 0
                _check_size(path, name, (nnz,), 16, limit)
                data = np.asarray(obj["data"][()]) if "data" in obj else np.zeros(0)
                ir = np.asarray(obj["ir"][()], dtype=np.int64) if "ir" in obj else np.zeros(0, np.int64)
                if data.dtype.kind not in "biuf":
                    raise ArrayError(f"{path}: sparse variable {name!r} is not real ({data.dtype})")
                try:  # row indices and pointers checked in full: scipy trusts them (a bad ir segfaulted)
                    A = sp.csc_matrix((data.astype(float), ir, jc), shape=(rows, max(len(jc) - 1, 0)))
                    A.check_format(full_check=True)
                except ValueError as exc:
                    raise ArrayError(f"{path}: sparse variable {name!r} is inconsistent ({exc})") from exc
                out[name] = A
            elif isinstance(obj, h5py.Dataset) and cls not in ("cell", "struct") and obj.dtype.kind in "biuf":
                if obj.attrs.get("MATLAB_empty", 0):
                    dims = tuple(int(d) for d in np.asarray(obj[()]).ravel())
                    out[name] = np.zeros(dims[::-1] if len(dims) == 2 else (0, 0))
                    continue
                _check_size(path, name, tuple(int(d) for d in obj.shape), obj.dtype.itemsize, limit)
                out[name] = np.asarray(obj[()]).T  # column-major MATLAB (k, d) is stored as (d, k)
            else:
                raise ArrayError(f"{path}: variable {name!r} is a MATLAB {cls or type(obj).__name__} "
                                 f"in a v7.3 file; {EXPORT_HINT}")
    return out


def load_mat(path: Path, names: Iterable[str], limit: int) -> dict:
    """The variables ``names`` found in the ``.mat`` file ``path``: numpy arrays in MATLAB's orientation,
    MATLAB sparse matrices as scipy CSC. v7.3 files (HDF5) are read with h5py, older ones with scipy."""
    import h5py

    reader: Callable = _load_v73 if h5py.is_hdf5(str(path)) else _load_v5
    return reader(path, list(names), limit)
