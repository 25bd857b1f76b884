"""Reading CalculiX results: nodal forces from the ``.dat`` file, K and M from ``.sti``/``.mas``/``.dof``.

``.dat`` (``*NODE PRINT ... RF``): one block per printed increment, headed
``forces (fx,fy,fz) for set NALL and time  0.1000000E+01`` and followed by
``node fx fy fz`` lines with 7 significant digits (``%13.6E``). The time is
the *total* time, so with one increment of length 1 per step the block of
step ``k`` (1-based) has time ``k``.

``.sti``/``.mas``: ``i j value`` lines (1-based, upper triangle including the
diagonal, 14 digits); ``.dof``: one ``node.direction`` per matrix row.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import scipy.sparse as sp

_HEADER = re.compile(r"^\s*forces \(fx,fy,fz\) for set (\S+) and time\s+(\S+)\s*$", re.M)


class ResultFormatError(ValueError):
    """A CalculiX result file does not hold what was expected."""


def read_dat_forces(path: str | Path, node_ids: np.ndarray, n_steps: int) -> np.ndarray:
    """Nodal forces (n_steps, n_nodes, 3) printed at the end of steps 1..n_steps.

    Raises :class:`ResultFormatError` naming the first step whose block is
    missing, or a node missing from a block.
    """
    text = Path(path).read_text(errors="replace")
    heads = list(_HEADER.finditer(text))
    by_time: dict[int, tuple[int, int]] = {}
    for i, m in enumerate(heads):
        t = float(m.group(2))
        k = int(round(t))
        end = heads[i + 1].start() if i + 1 < len(heads) else len(text)
        if abs(t - k) < 1e-6:
            by_time[k] = (m.end(), end)  # last block at the end of step k
    node_ids = np.asarray(node_ids, dtype=np.int64)
    pos = np.full(int(node_ids.max()) + 1, -1)
    pos[node_ids] = np.arange(len(node_ids))
    out = np.empty((n_steps, len(node_ids), 3))
    for k in range(1, n_steps + 1):
        if k not in by_time:
            raise ResultFormatError(
                f"{path}: no force block for step {k} of {n_steps} (found steps {sorted(by_time)[:5]}...)"
            )
        a, b = by_time[k]
        vals = _numbers(text[a:b], path)
        if vals.size % 4:
            raise ResultFormatError(f"{path}: malformed force block of step {k}")
        vals = vals.reshape(-1, 4)
        nodes = vals[:, 0].astype(np.int64)
        if len(nodes) != len(node_ids) or np.any(nodes > pos.size - 1) or np.any(pos[nodes] < 0):
            raise ResultFormatError(
                f"{path}: the force block of step {k} lists {len(nodes)} nodes, expected the {len(node_ids)} of NALL"
            )
        out[k - 1, pos[nodes]] = vals[:, 1:]
    return out


def _numbers(block: str, path) -> np.ndarray:
    try:
        return np.array(block.split(), dtype=float)
    except ValueError as exc:
        raise ResultFormatError(f"{path}: unexpected text in a force block: {exc}") from None


def read_dof(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Node ids and directions (1-based) of the matrix rows from a ``.dof`` file."""
    lines = Path(path).read_text().split()
    nodes = np.empty(len(lines), dtype=np.int64)
    dirs = np.empty(len(lines), dtype=np.int64)
    for i, s in enumerate(lines):
        n, _, d = s.partition(".")
        nodes[i], dirs[i] = int(n), int(d)
    return nodes, dirs


def read_matrix(path: str | Path, n: int) -> sp.csr_matrix:
    """Symmetric matrix (n, n) from a ``.sti``/``.mas`` upper-triangle file."""
    data = np.fromfile(str(path), sep=" ")
    if data.size % 3:
        raise ResultFormatError(f"{path}: expected 'i j value' triplets")
    data = data.reshape(-1, 3)
    i = data[:, 0].astype(np.int64) - 1
    j = data[:, 1].astype(np.int64) - 1
    if data.size and (i.min() < 0 or max(i.max(), j.max()) >= n):
        raise ResultFormatError(f"{path}: indices outside 1..{n}")
    v = data[:, 2]
    off = i != j
    rows = np.concatenate([i, j[off]])
    cols = np.concatenate([j, i[off]])
    return sp.csr_matrix((np.concatenate([v, v[off]]), (rows, cols)), shape=(n, n))
