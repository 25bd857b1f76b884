"""stepnf: will each vibration mode of a thin structure harden or soften?

stepnf drives a finite-element solver as a black box (prescribed nodal
displacements in, nodal forces out, plus the mass and stiffness matrices),
recovers the quadratic and cubic stiffness terms with STEP, and evaluates the
backbone coefficient T of each master mode by normal form (NF, and the
full-order direct normal form DNF) and by quadratic manifolds with modal
derivatives (MD, SMD).

``import stepnf`` imports no FE library; adapters live in their own
distributions registered under the entry-point group ``stepnf.solvers``.
"""
from __future__ import annotations

__version__ = "0.1.0"

from stepnf.runtime.limits import one_blas_thread

one_blas_thread()  # under `ulimit -v`, before numpy starts OpenBLAS (stepnf.runtime.limits)

from typing import TYPE_CHECKING  # noqa: E402

from stepnf.errors import AdapterError, SceneError, SolverRunError, StepnfError, UnknownSolverError  # noqa: E402
from stepnf.runtime.lazy import lazy_exports  # noqa: E402

#: The names below import numpy and scipy: loaded when first asked for (``stepnf.SolverAdapter``), so that
#: ``import stepnf`` itself imports nothing heavy and the command line (:mod:`stepnf.cli.console`) can turn a
#: memory limit too low for numpy into a message.
_LAZY = {"SolverAdapter": "plugin.adapter", "MethodResult": "nf.coefficient", "backbone_T": "nf.coefficient",
         "ModalModel": "plugin.modal_model", "run": "api.runner", "open": "api.reader:open_run", "RunView": "api.view"}


if TYPE_CHECKING:  # what the lazy names are, for type checkers
    from stepnf.plugin.adapter import SolverAdapter
    from stepnf.nf.coefficient import MethodResult, backbone_T
    from stepnf.plugin.modal_model import ModalModel
    from stepnf.api.reader import open_run as open  # noqa: A001 - stepnf.open, as io.open or h5py.File
    from stepnf.api.runner import run
    from stepnf.api.view import RunView


#: ``stepnf.SolverAdapter``, ``stepnf.run``, ``stepnf.open`` and the other :data:`_LAZY` names, imported on first use
__getattr__ = lazy_exports(__name__, _LAZY, globals())


#: ``open`` is left out on purpose: ``from stepnf import *`` must not replace the built-in ``open``
#: (``stepnf.open`` is there all the same).
__all__ = [
    "run", "RunView",
    "SolverAdapter", "ModalModel", "MethodResult", "backbone_T",
    "StepnfError", "SceneError", "AdapterError", "SolverRunError", "UnknownSolverError",
    "__version__",
]
