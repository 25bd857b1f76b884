"""Memory limits (``ulimit -v``) that OpenBLAS turns into a hang, made a message instead.

OpenBLAS (Debian 12's 0.3.21, numpy's and scipy's BLAS and LAPACK here) takes a work buffer of
128 MiB (134,221,824 bytes measured) at its first LAPACK call, one per thread, and when ``malloc``
fails it tries again forever: under an address-space limit (``RLIMIT_AS``) of 200 to 400 MB a
12-dof ``stepnf run`` spun in ``blas_memory_alloc`` inside ``eigh`` (and with two threads, the
buffers OpenBLAS starts with made it hang even at exit). So, only when such a limit is set:

* :func:`one_blas_thread` (``import stepnf`` calls it, before numpy is imported) sets
  ``OPENBLAS_NUM_THREADS=1`` unless the environment sets it: one buffer, not one per core;
* :func:`reserve_blas_buffer` (the command line calls it first) refuses with one line naming the
  limit (exit 3) when the buffers no longer fit beside what Python, numpy and scipy already take,
  else makes OpenBLAS take its buffer at once with a 2x2 Cholesky factorisation: OpenBLAS keeps it
  for the rest of the process, so a later shortage is a ``MemoryError`` (a message naming the
  stage), never a spin.

Measured with the 12-dof ``examples/polynomial.toml`` (``ulimit -v`` in kB): before, 150000 to 400000
hung (killed after 40 s), 600000 worked; now 110000 to 280000 are the message in about a second, 290000
and above run (the run peaks at ~280 MB of address space with one BLAS thread; with ``plot = true``,
at 300000 matplotlib does not fit: a warning, no figure, the results all there; 350000 draws it). Below ~105 MB Python cannot
import numpy and scipy at all: one line naming the limit (:func:`numpy_does_not_fit`, exit 3, at once; before,
their ``MemoryError`` traceback at import, exit 1), from :func:`reserve_blas_buffer`, which imports them
first, or from :mod:`stepnf.cli.console` when importing the command line fails so. When :func:`one_blas_thread`
changed OpenBLAS's thread count, :func:`reserve_blas_buffer` says so once on stderr. Without a limit
nothing changes.
"""
from __future__ import annotations

import os
import resource
import sys

from stepnf.errors import StepnfError

#: OpenBLAS's work buffer per thread (bytes): ``BUFFER_SIZE`` of Debian's build, seen in ``malloc``.
BLAS_BUFFER = 134_221_824
#: Room kept beside the buffers for what a run imports and computes afterwards (h5py, scipy.linalg, a
#: small model): a limit that leaves less is refused up front.
HEADROOM = 48 * 2**20


def address_space_limit() -> int | None:
    """The soft ``RLIMIT_AS`` of this process in bytes (``ulimit -v`` x 1024), None when unlimited."""
    soft, _hard = resource.getrlimit(resource.RLIMIT_AS)
    return None if soft == resource.RLIM_INFINITY else int(soft)


#: The thread count OpenBLAS would have had when :func:`one_blas_thread` made it one (said once by
#: :func:`reserve_blas_buffer`); None when it changed nothing.
_threads_before: int | None = None


def one_blas_thread() -> None:
    """Under an address-space limit, ``OPENBLAS_NUM_THREADS=1`` unless set (effective only before numpy's import)."""
    global _threads_before
    if address_space_limit() is not None and "OPENBLAS_NUM_THREADS" not in os.environ:
        before = openblas_default_threads()
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
        if before > 1 and "numpy" not in sys.modules:  # numpy already loaded: OpenBLAS kept its threads
            _threads_before = before


def openblas_default_threads() -> int:
    """The threads OpenBLAS starts without ``OPENBLAS_NUM_THREADS``: ``GOTO_NUM_THREADS``, else
    ``OMP_NUM_THREADS``, else one per core this process may run on; never more than those cores."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    for name in ("GOTO_NUM_THREADS", "OMP_NUM_THREADS"):
        value = os.environ.get(name, "")
        if value.isdigit() and int(value) > 0:
            return min(int(value), cores)
    return cores


def _address_space_used() -> int | None:
    """Bytes of address space this process maps now (``VmSize``), None where ``/proc`` has no answer."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _blas_threads() -> int:
    value = os.environ.get("OPENBLAS_NUM_THREADS", "")
    return int(value) if value.isdigit() and int(value) > 0 else os.cpu_count() or 1


def reserve_blas_buffer() -> None:
    """Under an address-space limit: refuse (:class:`StepnfError`) when OpenBLAS's buffers cannot fit,
    else have OpenBLAS take its buffer now (module docstring). Without a limit: nothing."""
    limit = address_space_limit()
    if limit is None:
        return
    try:  # measured with them loaded, as every command loads them
        import numpy as np
        import scipy.linalg.lapack as lapack
    except (MemoryError, ImportError) as exc:
        if short_of_memory(exc):
            raise StepnfError(numpy_does_not_fit(limit)) from exc
        raise
    used = _address_space_used()
    threads = _blas_threads()
    need = threads * BLAS_BUFFER + HEADROOM
    if used is not None and limit - used < need:
        mib = 2**20
        raise StepnfError(
            f"memory limit: the address-space limit (ulimit -v {limit // 1024}) is {limit / mib:.0f} MiB and "
            f"Python, numpy and scipy already take {used / mib:.0f} MiB; stepnf needs {need / mib:.0f} MiB more "
            f"(OpenBLAS's {BLAS_BUFFER / mib:.0f} MiB work buffer for each of its {threads} thread(s), and room "
            f"to compute), so at least ulimit -v {(used + need) // 1024 + 1}: raise or remove the limit")
    if _threads_before is not None:  # the one note of stepnf having changed OpenBLAS's threads (one_blas_thread)
        print(f"stepnf: note: under the address-space limit (ulimit -v {limit // 1024}) OpenBLAS runs on 1 thread "
              f"instead of {_threads_before} (its {BLAS_BUFFER // 2**20} MiB work buffer per thread); set "
              "OPENBLAS_NUM_THREADS to choose", file=sys.stderr)
    lapack.dpotrf(np.eye(2))  # OpenBLAS's buffer taken now, while there is room, and kept


def numpy_does_not_fit(limit: int | None) -> str:
    """The message (after "stepnf: error: ") for numpy and scipy not fitting at import under the address-space
    limit ``limit`` (bytes, None when unlimited)."""
    room = ("this machine's free memory is too little" if limit is None else
            f"the address-space limit (ulimit -v {limit // 1024}, RLIMIT_AS) is {limit / 2**20:.0f} MiB, too little")
    return (f"memory limit: {room} for Python to load the modules stepnf needs (numpy, scipy); raise or remove "
            "the limit (a small model runs from about ulimit -v 300000)")


def short_of_memory(exc: BaseException) -> bool:
    """``exc`` is a want of memory: a ``MemoryError``, a library that cannot be mapped ("failed to map
    segment", an ``ImportError``) or a thread without room for its stack ("can't start new thread", a
    ``RuntimeError``: matplotlib's font manager starts one) under an address-space limit."""
    return isinstance(exc, MemoryError) or (
        isinstance(exc, ImportError) and "failed to map segment" in str(exc)) or (
        isinstance(exc, RuntimeError) and "can't start new thread" in str(exc))


def out_of_memory(exc: BaseException) -> bool:
    """Say on stderr that ``exc`` is a want of memory (:func:`short_of_memory`), naming the stage
    (:class:`stepnf.runtime.progress.Progress` marks it) and any ``ulimit -v``; False (nothing said) otherwise."""
    if not short_of_memory(exc):
        return False
    limit = address_space_limit()
    stage = getattr(exc, "stepnf_stage", None)
    room = f"the address-space limit (ulimit -v {limit // 1024})" if limit else "this machine's memory"
    print(f"stepnf: out of memory{f' in stage {stage!r}' if stage else ''}: the model or a requested quantity "
          f"does not fit in {room}; use a coarser mesh, fewer modes, a higher limit or a machine with more memory",
          file=sys.stderr)
    return True
