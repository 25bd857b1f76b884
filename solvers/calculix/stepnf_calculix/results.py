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
import warnings
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from stepnf.errors import SolverRunError

_HEADER = re.compile(r"^\s*forces \(fx,fy,fz\) for set (\S+) and time\s+(\S+)\s*$", re.M)


class ResultFormatError(SolverRunError, ValueError):
    """A CalculiX result file does not hold what was expected.

    A solver failure (:class:`stepnf.errors.SolverRunError`, exit code 3 of the
    CLI) and still a :class:`ValueError`, as before it joined stepnf's errors.
    """


def read_dat_forces(path: str | Path, node_ids: np.ndarray, n_steps: int) -> np.ndarray:
    """Nodal forces (n_steps, n_nodes, 3) printed at the end of steps 1..n_steps.

    Raises :class:`ResultFormatError` naming the first step whose block is
    missing, or a node missing from a block.
    """
    text = Path(path).read_text(errors="replace")
    heads = list(_HEADER.finditer(text))
    by_time: dict[int, tuple[int, int]] = {}
    for i, m in enumerate(heads):
        try:
            t = float(m.group(2))
        except ValueError:
            raise ResultFormatError(f"{path}: unreadable time {m.group(2)!r} in the header "
                                    f"{m.group(0).strip()!r}") from None
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
                f"{path}: the force block of step {k} lists {len(nodes)} nodes, expected the {len(node_ids)} of "
                "the printed node set"
            )
        if np.any(vals[:, 0] != nodes):
            raise ResultFormatError(f"{path}: the force block of step {k} has a non-integer node number")
        bad = ~np.isfinite(vals[:, 1:])
        if bad.any():
            r = int(np.nonzero(bad.any(axis=1))[0][0])
            raise ResultFormatError(f"{path}: NaN or inf forces in step {k}, e.g. node {nodes[r]}: "
                                    f"{vals[r, 1:].tolist()} ({int(bad.sum())} entries); ccx probably diverged")
        out[k - 1, pos[nodes]] = vals[:, 1:]
    return out


def _numbers(block: str, path) -> np.ndarray:
    try:
        return np.array(block.split(), dtype=float)
    except ValueError as exc:
        raise ResultFormatError(f"{path}: unexpected text in a force block: {exc}") from None


def read_dof(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Node ids and directions (1-based) of the matrix rows from a ``.dof`` file."""
    lines = Path(path).read_text(errors="replace").split()
    nodes = np.empty(len(lines), dtype=np.int64)
    dirs = np.empty(len(lines), dtype=np.int64)
    for i, s in enumerate(lines):
        n, _, d = s.partition(".")
        try:
            nodes[i], dirs[i] = int(n), int(d)
        except ValueError:
            raise ResultFormatError(f"{path}: entry {i + 1} is {s[:40]!r}; expected 'node.direction' "
                                    "(e.g. '17.2')") from None
    return nodes, dirs


def read_matrix(path: str | Path, n: int) -> sp.csr_matrix:
    """Symmetric matrix (n, n) from a ``.sti``/``.mas`` upper-triangle file.

    Raises :class:`ResultFormatError` on text that is not ``i j value``
    triplets, indices outside ``1..n`` or not integers, NaN or inf values, and
    a missing diagonal entry (every translational dof of a solid has one: a
    missing one means a truncated file).
    """
    data = _numbers_of_file(path)
    if data.size % 3:
        raise ResultFormatError(f"{path}: {data.size} numbers, not 'i j value' triplets (a truncated file?)")
    data = data.reshape(-1, 3)
    ij = data[:, :2]
    if data.size and (not np.all(np.isfinite(ij)) or np.any(ij != np.round(ij))):
        raise ResultFormatError(f"{path}: non-integer row or column indices")
    i = ij[:, 0].astype(np.int64) - 1
    j = ij[:, 1].astype(np.int64) - 1
    if data.size and (min(i.min(), j.min()) < 0 or max(i.max(), j.max()) >= n):
        raise ResultFormatError(f"{path}: indices outside 1..{n}")
    v = data[:, 2]
    bad = ~np.isfinite(v)
    if bad.any():
        e = int(np.nonzero(bad)[0][0])
        raise ResultFormatError(f"{path}: {int(bad.sum())} NaN or inf values, e.g. entry ({i[e] + 1}, {j[e] + 1})")
    diag = np.zeros(n, dtype=bool)
    diag[i[i == j]] = True
    if not diag.all():
        miss = np.nonzero(~diag)[0]
        raise ResultFormatError(f"{path}: no diagonal entry for {len(miss)} of the {n} rows, e.g. row "
                                f"{miss[0] + 1} (a truncated file?)")
    off = i != j
    rows = np.concatenate([i, j[off]])
    cols = np.concatenate([j, i[off]])
    return sp.csr_matrix((np.concatenate([v, v[off]]), (rows, cols)), shape=(n, n))


def _numbers_of_file(path: str | Path) -> np.ndarray:
    """Every whitespace-separated number of a text file, or :class:`ResultFormatError` naming the first
    token that is not one. ``np.fromfile`` parses at C speed but silently stops at such a token, so the
    tokens are counted on the raw bytes and must all have been read (a Python list of the tokens
    would take ~10x the time and the memory on the matrices of a large model)."""
    raw = np.fromfile(str(path), dtype=np.uint8)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # "could not be read to its end": checked below
        data = np.fromfile(str(path), sep=" ")
    space = np.isin(raw, np.frombuffer(b" \t\n\r\v\f", dtype=np.uint8))
    starts = ~space & np.concatenate(([True], space[:-1]))  # first byte of each token
    if np.count_nonzero(starts) != data.size:
        at = int(np.flatnonzero(starts)[data.size])
        end = at + int(np.argmax(np.append(space[at:at + 40], True)))
        token = raw[at:end].tobytes().decode("utf-8", "replace")
        raise ResultFormatError(f"{path}: entry {data.size // 3 + 1} holds {token!r}; expected 'i j value' triplets")
    return data
