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

from .limits import one_blas_thread

one_blas_thread()  # under `ulimit -v`, before numpy starts OpenBLAS (stepnf.limits)

from .adapter import SolverAdapter  # noqa: E402
from .backbone import MethodResult, backbone_T  # noqa: E402
from .errors import AdapterError, SceneError, SolverRunError, StepnfError, UnknownSolverError  # noqa: E402
from .modal_model import ModalModel  # noqa: E402

__all__ = [
    "SolverAdapter", "ModalModel", "MethodResult", "backbone_T",
    "StepnfError", "SceneError", "AdapterError", "SolverRunError", "UnknownSolverError",
    "__version__",
]
