"""Drive an external FE solver through command templates and files (solver-independent).

An *external* solver is one stepnf cannot see inside: it reads input files
written from a template, runs as a separate process in a work folder, and
writes result files that stepnf parses. This module holds the pieces every such
adapter shares, and nothing specific to one FE code (no FE import):

:class:`CommandTemplate`
    Text with named placeholders ``${name}`` (``$$`` is a literal ``$``). An
    unfilled placeholder is an error naming it and the template file;
    :attr:`CommandTemplate.placeholders` lists them.
:func:`find_executable`
    Resolve a program name or path, or raise :class:`~stepnf.errors.SolverRunError`.
:class:`WorkFolder`
    A fresh folder per solver run (in the system temp folder or under a
    scene-given parent), removed or kept on exit by policy
    (``"never"``, ``"on_error"``, ``"always"``).
:func:`run_command`
    Run a command inside the work folder with a time-out, its output captured
    to a log file; a missing executable, a non-zero exit or a time-out raises
    :class:`~stepnf.errors.SolverRunError` with the work folder and the tail
    of the log.
:func:`require_files`
    Raise the same error when an expected output file is missing.
:class:`ExternalSolverAdapter`
    A :class:`~stepnf.adapter.SolverAdapter` base whose batch hook sends a
    whole batch of displacement fields to ONE solver run (split into chunks
    of :attr:`ExternalSolverAdapter.max_fields_per_run` when the solver limits
    it). A subclass implements :meth:`~ExternalSolverAdapter.write_force_job`
    and :meth:`~ExternalSolverAdapter.read_forces`. Results of the chunks
    already computed are cached, so a failure in a later chunk loses nothing
    (the error carries them as ``partial``) and a retry does not redo them.
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import signal
import subprocess
import tempfile
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np
import scipy.sparse as sp

from .adapter import SolverAdapter, nonfinite_forces, real_array
from .errors import SolverRunError, StepnfError, allowed

#: Work-folder keeping policies.
KEEP_POLICIES = ("never", "on_error", "always")


class TemplateError(StepnfError, ValueError):
    """A command template is malformed or a placeholder was left unfilled."""


# ---------------------------------------------------------------- templates
_PATTERN = re.compile(r"\$(?:(?P<escaped>\$)|\{(?P<braced>[A-Za-z_][A-Za-z0-9_]*)\}|(?P<invalid>))")


class CommandTemplate:
    """A solver command file with named placeholders ``${name}``.

    ``$$`` stands for a literal ``$``; any other ``$`` is an error (so a typo
    cannot silently pass through to the solver). Values are converted with
    ``str``; format numbers before rendering (e.g. ``%.13e`` for CalculiX).
    """

    def __init__(self, text: str, *, source: str | Path | None = None):
        self.text = text
        self.source = None if source is None else str(source)
        for m in _PATTERN.finditer(text):
            if m.group("invalid") is not None:
                line = text.count("\n", 0, m.start()) + 1
                raise TemplateError(
                    f"{self._where()}: line {line}: '$' must start a placeholder '${{name}}' or be doubled '$$'"
                )

    @classmethod
    def from_file(cls, path: str | Path) -> "CommandTemplate":
        """Read a template file (UTF-8)."""
        path = Path(path)
        if not path.is_file():
            raise TemplateError(f"template file {path} does not exist")
        return cls(path.read_text(encoding="utf-8"), source=path)

    def _where(self) -> str:
        return self.source or "<template>"

    @property
    def placeholders(self) -> list[str]:
        """Names of the placeholders, in order of first appearance."""
        seen: dict[str, None] = {}
        for m in _PATTERN.finditer(self.text):
            if m.group("braced"):
                seen.setdefault(m.group("braced"), None)
        return list(seen)

    def render(self, values: Mapping[str, Any] | None = None, /, **kw: Any) -> str:
        """Fill every placeholder; raise :class:`TemplateError` naming those left unfilled.

        Values for names the template does not use are ignored (a template may
        leave out what it does not need).
        """
        vals = dict(values or {}, **kw)
        missing = [p for p in self.placeholders if p not in vals]
        if missing:
            raise TemplateError(
                f"{self._where()}: placeholder(s) {missing} left unfilled; given {sorted(vals)}"
            )

        def sub(m: re.Match) -> str:
            return "$" if m.group("escaped") else str(vals[m.group("braced")])

        return _PATTERN.sub(sub, self.text)


# -------------------------------------------------------------- executables
def find_executable(program: str | Path, *, what: str = "solver") -> str:
    """Absolute path of ``program`` (a name on ``PATH`` or a path), or :class:`SolverRunError`."""
    prog = str(program)
    if os.sep in prog or (os.altsep and os.altsep in prog):
        p = Path(prog).expanduser()
        if p.is_file() and os.access(p, os.X_OK):
            return str(p.resolve())
        raise SolverRunError(f"{what} executable {prog!r} does not exist or is not executable")
    found = shutil.which(prog)
    if found is None:
        raise SolverRunError(
            f"{what} executable {prog!r} not found on PATH; install it or give its full path"
        )
    return found


def log_tail(path: str | Path, n_lines: int = 25, max_chars: int = 4000) -> str:
    """Last ``n_lines`` lines of a text file ('' when it does not exist)."""
    try:
        with open(path, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            size = fh.tell()
            fh.seek(max(0, size - 64 * 1024))
            data = fh.read().decode("utf-8", errors="replace")
    except OSError:
        return ""
    text = "\n".join(data.splitlines()[-n_lines:])
    return text[-max_chars:]


# -------------------------------------------------------------- work folders
class WorkFolder:
    """A fresh folder for one solver run, removed or kept on exit.

    Parameters
    ----------
    parent : folder in which to create it (created if needed); ``None``: the system temp folder
    prefix : name prefix of the folder
    keep : ``"never"`` (always remove), ``"on_error"`` (keep when the block raised), ``"always"``
    """

    def __init__(self, parent: str | Path | None = None, *, prefix: str = "stepnf-", keep: str = "on_error"):
        if keep not in KEEP_POLICIES:
            raise ValueError(f"unknown keep policy {keep!r}. Pick one of {allowed(KEEP_POLICIES)}")
        self.parent = None if parent is None else Path(parent)
        self.prefix = prefix
        self.keep = keep
        self.path: Path | None = None

    def __enter__(self) -> Path:
        if self.parent is not None:
            self.parent.mkdir(parents=True, exist_ok=True)
        self.path = Path(tempfile.mkdtemp(prefix=self.prefix, dir=self.parent))
        return self.path

    def __exit__(self, exc_type, exc, tb) -> None:
        failed = exc_type is not None
        if self.path is None:
            return
        if self.keep == "always" or (self.keep == "on_error" and failed):
            return
        shutil.rmtree(self.path, ignore_errors=True)


# ----------------------------------------------------------------- commands
@dataclass(frozen=True)
class RunRecord:
    """One finished solver run: command, folder, log file, wall time (s)."""

    argv: tuple[str, ...]
    workdir: Path
    log: Path
    seconds: float


def run_command(
    argv: Sequence[str | Path],
    *,
    cwd: str | Path,
    timeout: float | None = None,
    log_name: str = "solver.log",
    env: Mapping[str, str] | None = None,
    what: str = "solver",
) -> RunRecord:
    """Run ``argv`` in ``cwd``; stdout and stderr go to ``cwd/log_name``.

    ``argv[0]`` is resolved with :func:`find_executable`. ``env`` entries are
    added to the current environment. On time-out the whole process group is
    killed. Raises :class:`SolverRunError` (with the work folder and the tail
    of the log) on a missing executable, a non-zero exit or a time-out.
    """
    cwd = Path(cwd)
    log = cwd / log_name
    try:
        exe = find_executable(argv[0], what=what)
    except SolverRunError as exc:
        raise SolverRunError(str(exc).split("\n")[0], workdir=cwd) from None
    args = [exe] + [str(a) for a in argv[1:]]
    full_env = dict(os.environ)
    full_env.update(env or {})
    t0 = time.perf_counter()
    with open(log, "wb") as out:
        try:
            proc = subprocess.Popen(args, cwd=cwd, stdout=out, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL, env=full_env, start_new_session=True)
        except OSError as exc:
            raise SolverRunError(f"{what} could not start: {' '.join(args)}: {exc}", workdir=cwd) from exc
        try:
            rc = proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            _kill_group(proc)
            raise SolverRunError(
                f"{what} timed out after {timeout:g} s: {' '.join(args)}", workdir=cwd, log_tail=log_tail(log)
            ) from None
        except BaseException:
            _kill_group(proc)
            raise
    seconds = time.perf_counter() - t0
    if rc != 0:
        raise SolverRunError(
            f"{what} exited with code {rc}: {' '.join(args)}", workdir=cwd, log_tail=log_tail(log)
        )
    return RunRecord(tuple(args), cwd, log, seconds)


def _kill_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        proc.kill()
    proc.wait()


def require_files(workdir: str | Path, names: Sequence[str], *, log: str | Path | None = None,
                  what: str = "solver") -> list[Path]:
    """Paths of the expected output files; :class:`SolverRunError` naming the missing ones."""
    workdir = Path(workdir)
    paths = [workdir / n for n in names]
    missing = [p.name for p in paths if not p.is_file()]
    if missing:
        raise SolverRunError(
            f"{what} finished but did not write {missing}", workdir=workdir,
            log_tail=log_tail(log) if log is not None else "",
        )
    return paths


# ------------------------------------------------------------ adapter base
class ExternalSolverAdapter(SolverAdapter):
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

    def mass_matrix(self) -> sp.spmatrix:
        if getattr(self, "_M", None) is None:
            self._read_matrices_guarded()
        return self._M

    def stiffness_matrix(self) -> sp.spmatrix:
        if getattr(self, "_K", None) is None:
            self._read_matrices_guarded()
        return self._K

    def _read_matrices_guarded(self) -> None:
        """:meth:`_matrices`, with a result file it cannot parse reported as a :class:`SolverRunError`."""
        try:
            self._matrices()
        except StepnfError:
            raise
        except (ValueError, KeyError, IndexError, EOFError, OSError, zipfile.BadZipFile) as exc:
            raise SolverRunError(f"{self.solver_label}: cannot read K and M from the solver's output: "
                                 f"{type(exc).__name__}: {exc}") from None

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
        """Run the solver command ``argv`` (``argv[0]`` replaced by the configured executable)."""
        rec = run_command([self.executable, *argv[1:]], cwd=workdir, timeout=self.timeout,
                          log_name=log_name, env=self.run_env(), what=self.solver_label)
        self.runs.append(rec)
        return rec

    @staticmethod
    def _key(u: np.ndarray) -> bytes:
        return hashlib.sha1(np.ascontiguousarray(u, dtype=float).tobytes()).digest()

    def _internal_forces(self, U: np.ndarray) -> np.ndarray:
        keys = [self._key(u) for u in U]
        todo: list[int] = []
        pending: set[bytes] = set()
        for i, k in enumerate(keys):
            if k not in self._cache and k not in pending:
                todo.append(i)
                pending.add(k)
        runs = max(1, int(self.parallel_runs))
        size = max(1, -(-len(todo) // runs))  # split the batch evenly over the parallel runs
        if self.max_fields_per_run:
            size = min(size, int(self.max_fields_per_run))
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
            try:
                F = real_array(self.read_forces(wd, len(U)), "forces", self)
            except SolverRunError:
                raise
            except (StepnfError, ValueError, KeyError, IndexError, EOFError, OSError, zipfile.BadZipFile) as exc:
                raise SolverRunError(f"{self.solver_label}: cannot read the forces from the solver's output: "
                                     f"{exc}", workdir=wd, log_tail=log_tail(rec.log)) from None
            if F.shape != U.shape:
                raise SolverRunError(
                    f"{type(self).__name__}: read forces of shape {F.shape}, expected {U.shape}",
                    workdir=wd, log_tail=log_tail(rec.log),
                )
            problem = nonfinite_forces(F)
            if problem:
                raise SolverRunError(f"{self.solver_label}: {problem}", workdir=wd, log_tail=log_tail(rec.log))
        return F

    def clear_cache(self) -> None:
        """Forget the forces already computed."""
        self._cache.clear()

    def close(self) -> None:
        """Forget cached forces (work folders are removed after each run already)."""
        self._cache.clear()


def missing_output(workdir: str | Path, message: str, *, log_name: str = "solver.log") -> SolverRunError:
    """A :class:`SolverRunError` for a missing field in an output, with the log tail."""
    workdir = Path(workdir)
    return SolverRunError(message, workdir=workdir, log_tail=log_tail(workdir / log_name))


#: Ranges of the run settings: a time-out above 1e7 s (four months) is no time-out, no machine has
#: more than 1024 cores for one solver run, 256 solver runs at once already exceed any node's memory,
#: and 2^24 MB is 16 TiB. An integer setting not listed here only has to be >= 1.
RUN_RANGES: dict[str, tuple[float, float]] = {"timeout": (0.0, 1e7), "threads": (1, 1024), "ncpus": (1, 1024),
                                              "parallel_runs": (1, 256), "memory_mb": (1, 2**24)}


def run_keys(config: Mapping[str, Any], base_dir: Path, scene_file, ints: Sequence[str] = ("parallel_runs",)
             ) -> dict[str, Any]:
    """The run settings every external adapter takes from ``[model]``: ``timeout`` (s), ``workdir``
    (relative to the scene), ``keep`` (one of :data:`KEEP_POLICIES`) and the integers ``ints``, each
    within :data:`RUN_RANGES`."""
    from .errors import SceneError, allowed
    from .scene import check_number

    run: dict[str, Any] = {}
    if "timeout" in config:
        lo, hi = RUN_RANGES["timeout"]
        run["timeout"] = float(check_number(scene_file, "model.timeout", config["timeout"], lo=lo, hi=hi,
                                            lo_open=True, why=" (seconds)"))
    if "workdir" in config:
        run["workdir"] = Path(base_dir) / str(config["workdir"])
    if "keep" in config:
        if config["keep"] not in KEEP_POLICIES:
            raise SceneError(scene_file, "model.keep", f"got {config['keep']!r}. Pick one of {allowed(KEEP_POLICIES)}")
        run["keep"] = config["keep"]
    for key in ints:
        if key in config:
            lo, hi = RUN_RANGES.get(key, (1, None))
            run[key] = int(check_number(scene_file, f"model.{key}", config[key], integer=True, lo=lo, hi=hi))
    return run
