"""Checkpoints of force evaluations, so that a killed run resumes without redoing solver work.

Each chunk of displacement fields sent to the solver is stored, once its
forces are back, as one ``.npz`` file written atomically in a folder beside
the results (``<output>/.<name>.partial/``). A chunk is identified by its plan
name, its position and a *fingerprint* of its fields (their projections on a
fixed pseudo-random vector): a rerun reuses a stored chunk only when the
fingerprints agree to 1e-9 relative, i.e. when it asks for the same fields
(same modes, same amplitudes), whatever round-off the eigen-solver left. The
folder is removed once the run's results are written.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np


def fingerprint(U: np.ndarray) -> np.ndarray:
    """Projections of each field (row of U) on a fixed pseudo-random vector, plus its norm."""
    w = np.random.default_rng(12345).standard_normal(U.shape[1])
    return np.column_stack([U @ w, np.linalg.norm(U, axis=1)])


class Checkpoint:
    """A folder of atomically written chunks; see the module docstring."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.reused = 0

    def _path(self, plan: str, index: int) -> Path:
        return self.folder / f"{plan}_{index:06d}.npz"

    def load(self, plan: str, index: int, U: np.ndarray) -> np.ndarray | None:
        """Stored result of chunk ``index`` of ``plan`` if it was computed for the same fields."""
        path = self._path(plan, index)
        if not path.exists():
            return None
        try:
            with np.load(path) as z:
                fp, out = z["fingerprint"], z["result"]
        except Exception:  # a damaged chunk is recomputed, never trusted
            return None
        new = fingerprint(U)
        if fp.shape != new.shape or not np.allclose(fp, new, rtol=1e-9, atol=1e-9 * np.abs(new).max()):
            return None
        self.reused += len(U)
        return out

    def store(self, plan: str, index: int, U: np.ndarray, result: np.ndarray) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.folder, suffix=".tmp")
        os.close(fd)
        try:
            with open(tmp, "wb") as f:
                np.savez(f, fingerprint=fingerprint(U), result=result)
            os.replace(tmp, self._path(plan, index))
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)

    def discard(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)
