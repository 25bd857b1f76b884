"""The ``polynomial`` solver adapter: a system given by its tensors.

``f(u)_i = sum_j K_ij u_j + sum_jk G_ijk u_j u_k + sum_jkl H_ijkl u_j u_k u_l``

read from an ``.npz``, HDF5 (``.h5``/``.hdf5``) or MATLAB ``.mat`` file holding arrays ``M``
(n, n), ``K`` (n, n), ``G`` (n, n, n), ``H`` (n, n, n, n), or any of them as a coordinate list
(``G_subs`` (k, 3) and ``G_vals`` (k,), ...; 0-based, 1-based in ``.mat``; sparse M and K; see
:mod:`.sparse_tensors` and docs/adapters.md: forces then cost O(nnz)), and optionally
``coordinates`` (n, 3), ``directions`` (n,) (codes of
:data:`stepnf.plugin.adapter.DIRECTIONS`) and ``length`` (a characteristic length for
the automatic STEP amplitude). ``G`` and ``H`` are symmetrised in their lower
indices on loading (only that part acts in ``f``). Every array's header is checked before
its data is read: real (bool, int, float) dtypes only, never pickled objects, shapes that fit
``M`` (n, n), at most 1 GiB per array. Scene keys::

    [model]
    solver = "polynomial"
    file = "system.npz"      # relative to the scene
"""
from __future__ import annotations

from .adapter import PolynomialAdapter, load_system, save_system

__all__ = ["PolynomialAdapter", "load_system", "save_system"]
