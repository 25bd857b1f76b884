"""``mpirun`` for tests that run stepnf on several processes (FEniCSx adapters)."""
from __future__ import annotations

import os
import shutil
import subprocess

#: The MPI launcher on PATH, or None.
MPIRUN = shutil.which("mpirun") or shutil.which("mpiexec")


def mpirun_command(n: int) -> tuple[list[str], dict[str, str]]:
    """``mpirun -n n`` (Open MPI: oversubscription allowed, and allowed as root, e.g. in containers)."""
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    cmd = [MPIRUN, "-n", str(n)]
    version = subprocess.run([MPIRUN, "--version"], capture_output=True, text=True).stdout
    if "Open MPI" in version or "OpenRTE" in version:
        cmd.append("--oversubscribe")
        env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    return cmd, env
