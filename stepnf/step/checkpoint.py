"""Checkpoints of force evaluations, so that a killed run resumes without redoing solver work.

Each chunk of displacement fields sent to the solver is stored, once its
forces are back, as one ``.npz`` file written atomically in a folder beside
the results (``<output>/.<name>.partial/``). A chunk is identified by its plan
name, its position and a *fingerprint* of its fields (their projections on a
fixed pseudo-random vector): a rerun reuses a stored chunk only when the
fingerprints agree to 1e-9 relative, i.e. when it asks for the same fields
(same modes, same amplitudes), whatever round-off the eigen-solver left. The
folder is removed once the run's results are written.

The same fields give the same forces only from the same model, so the folder is
also keyed by the model, in two ways:

- *At the start*, the model's key (:func:`stepnf.scene.model_key.model_key`: the
  solver, the adapter and its version, the resolved ``[model]`` table and the
  SHA-256 of every input file the scene names) is compared with the one stored
  beside the chunks (``model_key.json``). Another key, or none (chunks of an
  earlier stepnf), drops every chunk with one warning naming the folder and
  what changed ("checkpoint in X was made for another model (model.file Y
  changed): not reused"). This is cheap (the files are hashed, nothing is
  computed) and explains itself.
- *At the first reuse*, a probe: the first field of the chunk about to be reused
  is sent to the solver again and its forces compared with the ones stored with
  the chunk (to :data:`PROBE_RTOL` of their largest entry). It catches what the
  scene cannot show (a file a deck includes, another build of the same adapter
  version, a solver executable upgraded in place) for one force evaluation per
  resumed run. A mismatch drops every chunk, with the same warning.

The folder is the user's alone (:mod:`stepnf.io.atomic`'s private folders):
created 0700 whatever the umask. One that others can write into (group- or
world-writable: in a shared output folder anyone may have made
``.NAME.partial/`` first, with a matching ``model_key.json`` and forged
chunks) is dropped with the same warning; one of another user (or a symbolic
link) is neither read nor removed: the run goes on without checkpoints, with
one warning naming it.

A mismatch recomputes rather than refuses: a checkpoint is a convenience, and a
run started again from the beginning is what the user asked for. Checkpoints
are never a reason to fail either: a chunk that cannot be written (full disk,
read-only folder) disables checkpointing for the rest of the run with one
warning, and the computation goes on.
"""
from __future__ import annotations

import io
import json
import os
import shutil
import stat
import warnings
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from stepnf.io.atomic import unsafe_reason, write_bytes
from stepnf.io.canonical import dumps
from stepnf.errors import OutputError, OutputWarning, StaleWarning

#: File beside the chunks holding the model key they were computed for.
KEY_FILE = "model_key.json"
#: The probe's forces must agree with the stored ones to this fraction of their largest entry. The
#: same field of the same model gives the same forces to round-off (1e-13 for a double-precision
#: assembly, a summation order changed by threads) or to the last digit a solver prints (CalculiX's
#: .dat file: 7 digits, one unit of the seventh at most 1e-6 of the largest entry); a model change
#: below 1e-5 of the forces is below what the STEP check (tolerance 1e-4) resolves anyway.
PROBE_RTOL = 1e-5


def _regular(path: Path) -> bool:
    """Whether ``path`` is a regular file, not followed if a link: a FIFO would block ``np.load`` for ever,
    a link is nothing stepnf wrote (chunks are written without following links)."""
    try:
        return stat.S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False


def fingerprint(U: np.ndarray) -> np.ndarray:
    """Projections of each field (row of U) on a fixed pseudo-random vector, plus its norm."""
    w = np.random.default_rng(12345).standard_normal(U.shape[1])
    return np.column_stack([U @ w, np.linalg.norm(U, axis=1)])


class Checkpoint:
    """A folder of atomically written chunks; see the module docstring.

    ``key``: the model key (:func:`stepnf.scene.model_key.model_key`) the chunks are computed for;
    ``describe(old, new)`` says what differs between two keys (``None``: the key is not checked).
    When a chunk cannot be written, one :class:`stepnf.errors.OutputWarning` says so (the CLI
    prints it as "stepnf: warning: ...") and no chunk is stored any more; chunks of another model
    are dropped with one :class:`stepnf.errors.StaleWarning`.
    """

    def __init__(self, folder: str | Path, key: Mapping[str, Any] | None = None,
                 describe: Callable[[Any, Mapping[str, Any]], str] | None = None):
        self.folder = Path(folder)
        self.reused = 0
        self.disabled: str | None = None  # why chunks are no longer stored
        self.key = key
        self.dropped: str | None = None  # why the stored chunks were not reused
        self._key_written = False
        self._probed = False
        self.refused: str | None = None  # why the folder is neither read nor written (not the user's)
        self._check_private()
        if key is not None and self.refused is None:
            self._check_key(describe or (lambda old, new: "another model key"))

    def _path(self, plan: str, index: int) -> Path:
        return self.folder / f"{plan}_{index:06d}.npz"

    def _check_private(self) -> None:
        """Drop a folder others can write into; refuse (use no checkpoint) one of another user or a link."""
        if not os.path.lexists(self.folder):
            return
        why = f"{self.folder} is a symbolic link" if self.folder.is_symlink() \
            else unsafe_reason(self.folder, parent=False)
        if why is None:
            return
        try:
            st = os.lstat(self.folder)
        except OSError:
            st = None
        if st is not None and not stat.S_ISLNK(st.st_mode) and st.st_uid == os.geteuid():  # ours, writable by others
            self._drop(f"is writable by others (mode {stat.S_IMODE(st.st_mode):04o}): another user could have put "
                       "forces in it")
            return
        self.refused = self.disabled = why
        warnings.warn(f"checkpointing disabled: {why}: not used (stepnf keeps its checkpoint folder private); "
                      "the run goes on without checkpoints (remove it to resume interrupted runs again)",
                      OutputWarning, stacklevel=3)

    def _check_key(self, describe: Callable[[Any, Mapping[str, Any]], str]) -> None:
        """Drop the stored chunks when they were computed for another model (or for an unknown one)."""
        if not self.folder.is_dir() or not any(self.folder.glob("*.npz")):
            return
        try:
            old = json.loads((self.folder / KEY_FILE).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            self._drop("was written without a model key (by an earlier stepnf)")
            return
        if dumps(old) != dumps(self.key):
            self._drop(f"was made for another model ({describe(old, self.key)})")  # type: ignore[arg-type]

    def _drop(self, why: str) -> None:
        """Warn once and remove every stored chunk (the run computes them again and stores its own)."""
        self.dropped = why
        warnings.warn(f"checkpoint in {self.folder} {why}: not reused; "
                      "the run starts again from the beginning", StaleWarning, stacklevel=3)
        shutil.rmtree(self.folder, ignore_errors=True)
        self._key_written = False

    def load(self, plan: str, index: int, U: np.ndarray,
             probe: Callable[[np.ndarray], np.ndarray] | None = None,
             shape: tuple[int, ...] | None = None) -> np.ndarray | None:
        """Stored result of chunk ``index`` of ``plan`` if it was computed for the same fields (and model).

        ``probe(U1)``: the solver's forces of the fields ``U1`` now, called once per run on the first
        chunk about to be reused (see the module docstring). ``shape``: the shape the result must have
        (the same fields reduced another way, e.g. projected on another number of modes, are not reused).
        """
        path = self._path(plan, index)
        if self.refused is not None or not _regular(path):
            return None
        try:
            with np.load(path) as z:
                fp, out = z["fingerprint"], z["result"]
                stored_probe = z["probe"] if "probe" in z.files else None
        except Exception:  # a damaged chunk is recomputed, never trusted
            return None
        if shape is not None and out.shape != tuple(shape):
            return None
        new = fingerprint(U)
        if fp.shape != new.shape or not np.allclose(fp, new, rtol=1e-9, atol=1e-9 * np.abs(new).max()):
            return None
        if probe is not None and not self._probed and len(U):
            if stored_probe is None:
                return None  # a chunk without its probe forces is not trusted
            scale = float(np.abs(stored_probe).max()) if stored_probe.size else 0.0
            now = np.asarray(probe(U[:1]), dtype=float)
            if now.shape != stored_probe.shape or not np.all(np.abs(now - stored_probe) <= PROBE_RTOL * scale):
                diff = float(np.abs(now - stored_probe).max() / scale) if now.shape == stored_probe.shape and scale \
                    else float("inf")
                self._drop(f"was made for another model (the solver's forces of a stored field differ by "
                           f"{diff:.1e} of their largest entry: the model changed where the scene does not show "
                           "it, e.g. in a file a deck includes or in the adapter)")
                return None
            self._probed = scale > 0  # a zero field proves nothing: probe the next chunk again
        self.reused += len(U)
        return out

    def store(self, plan: str, index: int, U: np.ndarray, result: np.ndarray,
              probe: np.ndarray | None = None) -> None:
        """Store one chunk (``probe``: the raw forces of its first field, for the probe of a rerun);
        on failure, warn once and store nothing more (the run goes on)."""
        if self.disabled is not None:
            return
        buf = io.BytesIO()
        arrays = {"fingerprint": fingerprint(U), "result": result}
        if probe is not None:
            arrays["probe"] = probe
        np.savez(buf, **arrays)
        data = buf.getbuffer()
        for attempt in (0, 1):
            try:
                if self.key is not None and not self._key_written:
                    write_bytes(self.folder / KEY_FILE, dumps(self.key).encode("utf-8"),
                                what="checkpoint model key", private_folder=True)
                    self._key_written = True
                write_bytes(self._path(plan, index), data, what="checkpoint chunk", private_folder=True)
                return
            except OutputError as exc:
                # another run of the same scene may have just removed the folder: try once more
                if attempt == 0 and isinstance(exc.__cause__, FileNotFoundError):
                    self._key_written = False
                    continue
                self.disabled = str(exc)
                warnings.warn(f"checkpointing disabled: {exc}; the run goes on without checkpoints "
                              "(an interrupted run will start again from the beginning)", OutputWarning,
                              stacklevel=2)
                return

    def discard(self) -> None:
        """Remove the folder (the run's results are written); one not the user's is left alone."""
        if self.refused is None:
            shutil.rmtree(self.folder, ignore_errors=True)
