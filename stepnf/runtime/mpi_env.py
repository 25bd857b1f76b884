"""Can MPI start here? Open MPI's session folder, checked before petsc4py or mpi4py is first imported.

Importing ``petsc4py.PETSc`` (or ``mpi4py.MPI``, or dolfinx) initialises MPI. Open MPI first creates
its session folder under the temporary folder it reads from the environment (``OMPI_MCA_orte_tmpdir_base``,
else ``TMPDIR``, ``TEMP``, ``TMP``, else ``/tmp``: Open MPI 4's ``opal_tmp_directory``), creating
missing parents; when it cannot, it prints about 50 lines and aborts the whole process, which no
Python code can catch. So stepnf asks :func:`mpi_tmpdir_problem` first:

* where PETSc is only faster (block products, MUMPS in ``linear_solver = "auto"``), it keeps scipy's
  path (:mod:`stepnf.linalg.block_product`: equal numbers; :mod:`stepnf.linalg.factorization`: SuperLU, with a warning);
* where MPI is needed (adapters whose ``uses_mpi`` is set, FEniCSx; ``linear_solver = "mumps"``),
  :func:`require_mpi` raises a one-line :class:`~stepnf.errors.StepnfError` naming the variable (exit 3).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

from stepnf.errors import StepnfError

#: Where Open MPI reads its temporary folder, in its order of preference.
TMPDIR_VARIABLES = ("OMPI_MCA_orte_tmpdir_base", "TMPDIR", "TEMP", "TMP")


def mpi_tmpdir() -> tuple[str, Path]:
    """``(variable, folder)``: the temporary folder Open MPI will use and the variable that named it
    (``("default", /tmp)`` when none is set)."""
    for var in TMPDIR_VARIABLES:
        value = os.environ.get(var)
        if value:
            return var, Path(value)
    return "default", Path("/tmp")


def mpi_tmpdir_problem() -> str | None:
    """Why Open MPI could not create its session folder here (one sentence), or None when it can.

    The folder must be a writable directory, or not exist yet under a writable directory (Open MPI
    creates the missing levels): writable is tried (a folder created and removed), since ``os.access``
    says yes to root where nothing can be created (``/proc``, a read-only mount). Its path must hold no
    ``[``: Open MPI 4 aborts at ``MPI_Init`` then ("Comm failure"; ``]``, spaces, quotes, control
    characters and paths of 1159 characters start, checked on Debian 12).
    """
    if "petsc4py.PETSc" in sys.modules or "mpi4py.MPI" in sys.modules:  # MPI already started
        return None
    var, folder = mpi_tmpdir()
    name = f"{var}={folder}" if var != "default" else str(folder)
    if "[" in str(folder):
        return f"{name} holds a '[', which Open MPI cannot use in its session folder's path"
    path = folder
    while not os.path.lexists(path):
        if path.parent == path:
            break
        path = path.parent
    if not path.is_dir():
        what = "is not a folder" if path == folder else f"cannot be created ({path} is not a folder)"
        return f"{name} {what}"
    if not os.access(path, os.W_OK | os.X_OK) or not _can_create(path):
        what = "is not writable" if path == folder else f"cannot be created ({path} is not writable)"
        return f"{name} {what}"
    return None


def _can_create(folder: Path) -> bool:
    """Whether a folder can be created in ``folder`` (one is, and removed at once)."""
    import tempfile

    try:
        os.rmdir(tempfile.mkdtemp(prefix=".stepnf-mpi-check-", dir=folder))
    except OSError:
        return False
    return True


def require_mpi(what: str) -> None:
    """Raise a one-line :class:`StepnfError` when MPI cannot start here; ``what`` needs it."""
    problem = mpi_tmpdir_problem()
    if problem is not None:
        raise StepnfError(f"{what} needs MPI, and Open MPI cannot start: its temporary folder {problem}; "
                          "set TMPDIR to a writable folder")
