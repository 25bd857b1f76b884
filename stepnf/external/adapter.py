"""The base of adapters that run an external program once per batch of displacement fields."""
from __future__ import annotations

import hashlib
import threading
import time
import zipfile
from pathlib import Path
from typing import ClassVar, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.plugin.adapter import SolverAdapter, checked_forces
from stepnf.errors import SolverRunError, StepnfError, allowed
from stepnf.plugin.lazy_matrices import LazyMatrices
from stepnf.external.process import KEEP_POLICIES, RunRecord, WorkFolder, log_tail, run_command
from stepnf.step.forces import solver_run_size

#: Held while a program's notice is printed (:meth:`ExternalSolverAdapter.run`); one lock for every adapter
#: (a module-level lock keeps adapters picklable).
_ANNOUNCING = threading.Lock()


class ExternalSolverAdapter(LazyMatrices, SolverAdapter):
    """Base of adapters that run an external program once per batch of displacement fields.

    Subclasses set :attr:`program` (default executable) and implement

    * :meth:`write_force_job` ``(workdir, U) -> argv``: write the input files
      for the fields ``U`` (m, n) and return the command to run there;
    * :meth:`read_forces` ``(workdir, m) -> F`` (m, n): parse the results,
      raising :class:`SolverRunError` (e.g. via :func:`missing_output`) when a
      field is missing;

    plus ``n_dofs`` and :meth:`_matrices` (a run that stores K and M in
    ``self._K`` and ``self._M``; :meth:`mass_matrix` and
    :meth:`stiffness_matrix` call it once). Run settings
    (constructor keywords, usually scene keys): ``executable``, ``timeout``
    (s, per run), ``workdir`` (parent of the work folders; default the temp
    folder), ``keep`` (one of :data:`KEEP_POLICIES`) and ``parallel_runs``
    (solver processes at a time, each on a share of the batch).
    """

    prefers_batches: ClassVar[bool] = True
    #: Program name used when ``executable`` is not given.
    program: ClassVar[str] = ""
    #: Largest number of fields per solver run (``None``: no limit; an instance may set its own).
    max_fields_per_run: int | None = None
    #: Number of computed force vectors kept (identical fields are not sent twice).
    cache_size: int = 512
    #: Solver processes run at the same time, each on a share of a batch (threads wait on them).
    parallel_runs: int = 1
    #: The scene keys that named the program run (set by ``from_config`` when the user allowed them,
    #: :mod:`stepnf.runtime.programs`): the full command is then printed on stderr before it first runs.
    program_named_by: str | None = None
    _announced: bool = False

    def __init__(self, *, executable: str | None = None, timeout: float | None = 3600.0,
                 workdir: str | Path | None = None, keep: str = "on_error", parallel_runs: int = 1):
        if keep not in KEEP_POLICIES:
            raise ValueError(f"unknown keep policy {keep!r}. Pick one of {allowed(KEEP_POLICIES)}")
        self.executable = executable or self.program
        self.timeout = timeout
        self.workdir = None if workdir is None else Path(workdir)
        self.keep = keep
        if isinstance(parallel_runs, bool) or not isinstance(parallel_runs, int) or parallel_runs < 1:
            raise ValueError(f"parallel_runs must be a positive integer, got {parallel_runs!r}")
        self.parallel_runs = parallel_runs
        self.runs: list[RunRecord] = []
        self._cache: dict[bytes, np.ndarray] = {}

    # hooks ------------------------------------------------------------
    def _matrices(self) -> None:
        """Hook: run the solver once to store ``self._K`` and ``self._M`` (scipy sparse, dof order)."""
        raise NotImplementedError(f"{type(self).__name__} does not export its matrices")

    def _build_matrices(self) -> tuple[sp.spmatrix, sp.spmatrix]:
        """K and M from one :meth:`_matrices` run (:class:`~stepnf.plugin.lazy_matrices.LazyMatrices` keeps them);
        a result file it cannot parse is a :class:`SolverRunError`."""
        try:
            self._matrices()
        except StepnfError:
            raise
        except (ValueError, KeyError, IndexError, EOFError, OSError, zipfile.BadZipFile) as exc:
            raise SolverRunError(f"{self.solver_label}: cannot read K and M from the solver's output: "
                                 f"{type(exc).__name__}: {exc}") from None
        return self._K, self._M

    def write_force_job(self, workdir: Path, U: np.ndarray) -> Sequence[str]:
        """Write the solver input for the fields ``U`` (m, n) into ``workdir``; return the command."""
        raise NotImplementedError

    def read_forces(self, workdir: Path, m: int) -> np.ndarray:
        """Parse the internal forces (m, n) of the run in ``workdir``."""
        raise NotImplementedError

    # machinery --------------------------------------------------------
    def work_folder(self, prefix: str) -> WorkFolder:
        """A :class:`WorkFolder` with this adapter's parent folder and keep policy."""
        return WorkFolder(self.workdir, prefix=prefix, keep=self.keep)

    def run_env(self) -> dict[str, str]:
        """Environment variables added for the solver runs (e.g. thread counts)."""
        return {}

    @property
    def solver_label(self) -> str:
        """How error messages name the solver."""
        return f"{type(self).__name__} ({self.executable})"

    def run(self, argv: Sequence[str], workdir: Path, *, log_name: str = "solver.log") -> RunRecord:
        """Run the solver command ``argv`` (``argv[0]`` replaced by the configured executable); a program the
        scene named is printed on stderr before its first run."""
        argv = [self.executable, *argv[1:]]
        if self.program_named_by and not self._announced:
            from stepnf.runtime import programs

            with _ANNOUNCING:  # parallel runs (threads): one notice, and none starts before it is printed
                if not self._announced:
                    programs.announce(argv, f"named by {self.program_named_by}")
                    self._announced = True
        rec = run_command(argv, cwd=workdir, timeout=self.timeout,
                          log_name=log_name, env=self.run_env(), what=self.solver_label)
        self.runs.append(rec)
        return rec

    @staticmethod
    def _key(u: np.ndarray) -> bytes:
        return hashlib.sha1(np.ascontiguousarray(u, dtype=float).tobytes()).digest()

    def _internal_forces(self, U: np.ndarray) -> np.ndarray:
        """The forces of ``U`` (m, n): fields not cached go to runs of :func:`~stepnf.step.forces.solver_run_size`
        fields. With a dict ``self.timings``, the wall-clock seconds are summed under ``"forces"``."""
        t0 = time.perf_counter()
        F = self._forces_of_runs(U)
        timings = getattr(self, "timings", None)
        if isinstance(timings, dict):
            timings["forces"] = timings.get("forces", 0.0) + time.perf_counter() - t0
        return F

    def _forces_of_runs(self, U: np.ndarray) -> np.ndarray:
        keys = [self._key(u) for u in U]
        todo: list[int] = []
        pending: set[bytes] = set()
        for i, k in enumerate(keys):
            if k not in self._cache and k not in pending:
                todo.append(i)
                pending.add(k)
        runs = max(1, int(self.parallel_runs))
        size = solver_run_size(len(todo), runs, self.max_fields_per_run)  # the one batching policy
        chunks = [todo[i:i + size] for i in range(0, len(todo), size)]
        errors: list[SolverRunError] = []

        def one(rows: list[int]) -> None:
            try:
                F = self._run_batch(U[rows])
            except SolverRunError as exc:
                errors.append(exc)
                return
            for i, f in zip(rows, F):
                self._cache[keys[i]] = f

        if runs > 1 and len(chunks) > 1:
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(max_workers=runs) as pool:
                list(pool.map(one, chunks))
        else:
            for rows in chunks:
                one(rows)
                if errors:
                    break
        if errors:
            exc = errors[0]
            exc.partial = {i: self._cache[k] for i, k in enumerate(keys) if k in self._cache}
            raise exc
        out = np.stack([self._cache[k] for k in keys])
        while len(self._cache) > max(self.cache_size, 0):  # drop the oldest entries
            self._cache.pop(next(iter(self._cache)))
        return out

    def _run_batch(self, U: np.ndarray) -> np.ndarray:
        with self.work_folder(prefix=f"{self.name or 'solver'}-forces-") as wd:
            argv = self.write_force_job(wd, U)
            rec = self.run(argv, wd)
            # the result files enter here: whatever is wrong with them (garbage, truncation, NaN) is a
            # solver failure that names the work folder (kept: on_error) and quotes the solver's log
            def fail(message: str) -> SolverRunError:  # a wrong shape or a NaN: the run failed
                return SolverRunError(message, workdir=wd, log_tail=log_tail(rec.log))

            try:  # the one check of forces (stepnf.plugin.adapter.checked_forces), where they are read
                F = checked_forces(self.read_forces(wd, len(U)), len(U), self, n=U.shape[1], what="forces",
                                   read_from=self.solver_label, fail=fail)
            except SolverRunError:
                raise
            except (StepnfError, ValueError, KeyError, IndexError, EOFError, OSError, zipfile.BadZipFile) as exc:
                raise SolverRunError(f"{self.solver_label}: cannot read the forces from the solver's output: "
                                     f"{exc}", workdir=wd, log_tail=log_tail(rec.log)) from None
        return F

    def clear_cache(self) -> None:
        """Forget the forces already computed."""
        self._cache.clear()

    def close(self) -> None:
        """Forget cached forces (work folders are removed after each run already)."""
        self._cache.clear()
