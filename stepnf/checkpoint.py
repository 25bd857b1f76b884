"""Checkpoints of force evaluations, so that a killed run resumes without redoing solver work.

Each chunk of displacement fields sent to the solver is stored, once its
forces are back, as one ``.npz`` file written atomically in a folder beside
the results (``<output>/.<name>.partial/``). A chunk is identified by its plan
name, its position and a *fingerprint* of its fields (their projections on a
fixed pseudo-random vector): a rerun reuses a stored chunk only when the
fingerprints agree to 1e-9 relative, i.e. when it asks for the same fields
(same modes, same amplitudes), whatever round-off the eigen-solver left. The
folder is removed once the run's results are written.

Checkpoints are a convenience, never a reason to fail: a chunk that cannot be
written (full disk, read-only folder) disables checkpointing for the rest of
the run with one warning, and the computation goes on.
"""
from __future__ import annotations

import io
import shutil
import warnings
from pathlib import Path

import numpy as np

from .atomic import write_bytes
from .errors import OutputError, OutputWarning


def fingerprint(U: np.ndarray) -> np.ndarray:
    """Projections of each field (row of U) on a fixed pseudo-random vector, plus its norm."""
    w = np.random.default_rng(12345).standard_normal(U.shape[1])
    return np.column_stack([U @ w, np.linalg.norm(U, axis=1)])


class Checkpoint:
    """A folder of atomically written chunks; see the module docstring.

    When a chunk cannot be written, one :class:`stepnf.errors.OutputWarning` says so (the CLI
    prints it as "stepnf: warning: ...") and no chunk is stored any more.
    """

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.reused = 0
        self.disabled: str | None = None  # why chunks are no longer stored

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
        """Store one chunk; on failure, warn once and store nothing more (the run goes on)."""
        if self.disabled is not None:
            return
        buf = io.BytesIO()
        np.savez(buf, fingerprint=fingerprint(U), result=result)
        data = buf.getbuffer()
        for attempt in (0, 1):
            try:
                write_bytes(self._path(plan, index), data, what="checkpoint chunk")
                return
            except OutputError as exc:
                # another run of the same scene may have just removed the folder: try once more
                if attempt == 0 and isinstance(exc.__cause__, FileNotFoundError):
                    continue
                self.disabled = str(exc)
                warnings.warn(f"checkpointing disabled: {exc}; the run goes on without checkpoints "
                              "(an interrupted run will start again from the beginning)", OutputWarning,
                              stacklevel=2)
                return

    def discard(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)
