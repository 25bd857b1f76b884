"""The solver-adapter protocol: how stepnf talks to a finite-element code.

An adapter wraps one FE model of one solver. stepnf only ever asks it for

* the number of dofs, and (optionally) the node coordinate and direction of
  every dof;
* the mass matrix ``M`` and the linear stiffness matrix ``K`` (sparse,
  symmetric, in the solver's own units, constrained dofs removed);
* the internal force ``f(u)`` for prescribed displacement fields ``u``
  (one field or a batch), with the sign convention of ``K u`` (so that
  ``M x'' + f(x) = 0``).

Implement **either** :meth:`SolverAdapter._internal_force` (one field; an
in-process solver) **or** :meth:`SolverAdapter._internal_forces` (a batch; a
file-driven external solver, so that one solver launch serves a whole STEP
plan). Each defaults to the other, as in scipy's ``LinearOperator``. The public
methods :meth:`internal_force` and :meth:`internal_forces` check shapes and
finiteness and then call the hooks.

Optional capabilities are declared with class flags and have default
implementations that raise:

``provides_eigenmodes``
    :meth:`eigenmodes` solves the generalised eigenproblem inside the solver
    (e.g. SLEPc under MPI).
``provides_shifted_solves``
    :meth:`shifted_solver` factorises ``K - sigma M`` inside the solver.
``provides_intrusive_tensors``
    :meth:`quadratic_force` and :meth:`cubic_force` give the exact ``G(u, v)``
    and ``H(u, v, w)`` (for regression tests of the non-intrusive route).

Output mesh: :meth:`SolverAdapter.output_mesh` (default ``None``) may return
a :class:`stepnf.io.fields.OutputMesh` (points and meshio cell blocks); stepnf
then writes the mode shapes and second-order fields for ParaView, placing
each dof at the point nearest its :meth:`~SolverAdapter.dof_coordinates`
(so the mesh's points must include the dofs' nodes).

Scene keys: an adapter declares the keys of its ``[model]`` table in
``model_keys`` (a :class:`stepnf.keys.schema.Schema`), and may override
``validate_config`` (checks across keys; pure) and ``from_config`` (the
build); see :class:`stepnf.keys.schema.FromScene`. stepnf checks a scene's
``[model]`` when it reads the scene, before anything is built, and
``stepnf solvers --keys NAME`` lists the declared keys.

Units are the solver's own (stepnf never assumes SI). Displacements and forces
are plain float64 numpy arrays ordered like the rows of ``M`` and ``K``.
"""
from __future__ import annotations

from typing import Any, Callable, ClassVar, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.errors import AdapterError
from stepnf.keys.schema import FromScene

#: Direction codes of :meth:`SolverAdapter.dof_directions`.
DIRECTIONS = ("ux", "uy", "uz", "rx", "ry", "rz")


class SolverAdapter(FromScene):
    """Base class of every solver adapter (see the module docstring)."""

    #: Entry-point name (informative; the registry uses the entry-point name).
    name: ClassVar[str] = ""
    #: The solver computes eigenmodes itself (:meth:`eigenmodes`).
    provides_eigenmodes: ClassVar[bool] = False
    #: The solver factorises ``K - sigma M`` itself (:meth:`shifted_solver`).
    provides_shifted_solves: ClassVar[bool] = False
    #: The solver offers exact ``G`` and ``H`` (:meth:`quadratic_force`, :meth:`cubic_force`).
    provides_intrusive_tensors: ClassVar[bool] = False
    #: Evaluating many fields in one call is much cheaper than one by one.
    prefers_batches: ClassVar[bool] = False
    #: The solver gives the tangent stiffness at a prescribed field (:meth:`tangent_stiffness`),
    #: more precisely than its printed forces: STEP can use it (``[analysis.step] method = "tangent"``).
    provides_tangent_stiffness: ClassVar[bool] = False
    #: Every MPI rank runs the pipeline together (the adapter gathers its results to all ranks):
    #: calls must happen on every rank in the same order, so no force checkpoint is reused.
    collective: ClassVar[bool] = False
    #: Building the model starts MPI (the adapter imports mpi4py, petsc4py or dolfinx): stepnf first checks
    #: that Open MPI can start here (:func:`stepnf.runtime.mpi_env.require_mpi`), a one-line message otherwise.
    uses_mpi: ClassVar[bool] = False
    #: STEP amplitude (fraction of the characteristic length) this solver works best with, when the
    #: scene gives none; e.g. larger for a solver that prints few digits. ``None``: stepnf's default.
    step_relative_amplitude: ClassVar[float | None] = None
    #: Significant decimal digits of the forces :meth:`internal_forces` returns when the solver prints
    #: them rounded (CalculiX's ``.dat``: 7); ``None``: double precision. The conformance harness bounds
    #: the rounding of its finite differences with it (:func:`stepnf.testing.harness.check_conservative_force`).
    force_digits: ClassVar[int | None] = None

    # ------------------------------------------------------------------ set-up
    def close(self) -> None:
        """Release solver resources (work folders, processes). Idempotent."""

    def __enter__(self) -> "SolverAdapter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------ required API
    @property
    def n_dofs(self) -> int:
        """Number of free dofs (rows of ``M`` and ``K``)."""
        raise NotImplementedError

    def mass_matrix(self) -> sp.spmatrix:
        """Mass matrix ``M`` (n, n), symmetric positive definite, sparse."""
        raise NotImplementedError

    def stiffness_matrix(self) -> sp.spmatrix:
        """Linear stiffness ``K = df/du(0)`` (n, n), symmetric, sparse."""
        raise NotImplementedError

    def _internal_force(self, u: np.ndarray) -> np.ndarray:
        """Hook: internal force for one field ``u`` (n,). Defaults to the batch hook."""
        if type(self)._internal_forces is SolverAdapter._internal_forces:
            raise NotImplementedError(
                f"{type(self).__name__} implements neither _internal_force nor _internal_forces"
            )
        return self._internal_forces(u[None, :])[0]

    def _internal_forces(self, U: np.ndarray) -> np.ndarray:
        """Hook: internal forces for a batch ``U`` (m, n), one field per row."""
        if type(self)._internal_force is SolverAdapter._internal_force:
            raise NotImplementedError(
                f"{type(self).__name__} implements neither _internal_force nor _internal_forces"
            )
        out = np.empty((len(U), self.n_dofs))  # filled field by field: no list stacked afterwards
        for i, u in enumerate(U):
            f = self._internal_force(u)
            if not (isinstance(f, np.ndarray) and f.shape == (self.n_dofs,) and f.dtype.kind in "fiu"):
                # not a plain real field: everything as returned, for internal_forces' checks to name it
                return np.stack([out[j] for j in range(i)] + [f] + [self._internal_force(v) for v in U[i + 1:]])
            out[i] = f
        return out

    # ------------------------------------------------------------- public API
    def internal_force(self, u: np.ndarray) -> np.ndarray:
        """Internal force ``f(u)`` (n,) for one displacement field ``u`` (n,)."""
        u = self._check_field(u)
        return checked_forces(self._internal_force(u), 1, self, what="internal force")[0]

    def internal_forces(self, U: np.ndarray) -> np.ndarray:
        """Internal forces (m, n) for a batch of fields ``U`` (m, n)."""
        U = np.asarray(U, dtype=float)
        if U.ndim != 2 or U.shape[1] != self.n_dofs:
            raise AdapterError(
                f"{type(self).__name__}.internal_forces: expected fields of shape (m, {self.n_dofs}), got {U.shape}"
            )
        if not np.all(np.isfinite(U)):
            raise AdapterError("prescribed displacement fields contain NaN or inf")
        if len(U) == 0:
            return np.zeros((0, self.n_dofs))
        return checked_forces(self._internal_forces(U), len(U), self)

    def _check_field(self, u: np.ndarray) -> np.ndarray:
        u = np.asarray(u, dtype=float)
        if u.shape != (self.n_dofs,):
            raise AdapterError(
                f"{type(self).__name__}.internal_force: expected a field of shape ({self.n_dofs},), got {u.shape}"
            )
        if not np.all(np.isfinite(u)):
            raise AdapterError("prescribed displacement field contains NaN or inf")
        return u

    # -------------------------------------------------------- optional geometry
    def dof_coordinates(self) -> np.ndarray | None:
        """Coordinates (n, 3) of the node carrying each dof, or ``None``."""
        return None

    def dof_directions(self) -> np.ndarray | None:
        """Direction code (n,) of each dof: index into :data:`DIRECTIONS`, or ``None``.

        Codes 0-2 are translations (model length units), 3-5 rotations (radians, a shell's nodes); stepnf
        measures displacements on the translations only (:mod:`stepnf.plugin.dofs`)."""
        return None

    def characteristic_length(self) -> float | None:
        """Length (model units) at which the model becomes nonlinear, e.g. a shell's thickness.

        Used by the automatic STEP amplitude. The default is the smallest
        extent of the bounding box of the dof coordinates (the thickness of a
        plate), or ``None`` when the adapter has no coordinates.
        """
        X = self.dof_coordinates()
        if X is None or len(X) == 0:
            return None
        ext = np.ptp(np.asarray(X, dtype=float), axis=0)
        ext = ext[ext > 0]
        return float(ext.min()) if ext.size else None

    def free_dof_map(self) -> Any | None:
        """A :class:`stepnf.plugin.boundary.FreeDofs` when boundary conditions removed dofs: how the dofs this
        adapter exposes sit among all the dofs of its mesh (stored with the results, so fields can be
        mapped back to the whole mesh); ``None`` when every dof is free."""
        return None

    def output_mesh(self) -> Any | None:
        """A :class:`stepnf.io.fields.OutputMesh` to write fields on (the whole mesh, fixed nodes included), or
        ``None`` (no field files). Needs :meth:`dof_coordinates` and :meth:`dof_directions`."""
        return None

    def mode_labels(self, Phi: np.ndarray) -> list[Any]:
        """Labels of the mode shapes (columns of ``Phi``), e.g. ``(k, n)`` tuples; ``None`` when unknown."""
        return [None] * Phi.shape[1]

    def transverse_amplitude(self, phi: np.ndarray) -> float | None:
        """Largest transverse mid-surface displacement of a mode shape (for Gamma), or ``None``."""
        return None

    def transverse_displacements(self, Phi: np.ndarray) -> np.ndarray | None:
        """The transverse mid-surface displacements (t, k) of the fields ``Phi`` (n, k), or ``None``.

        Optional, for a model whose :meth:`transverse_amplitude` is the largest ``|w|`` over t points
        with ``w`` linear in the field: then ``transverse_amplitude(phi) = max |w(phi)|``, and the
        backbone's W_max/h over a period is computed on the t x k values at once instead of one call
        of :meth:`transverse_amplitude` per phase. ``None`` (the default): not offered.
        """
        return None

    def shell_scales(self) -> Any | None:
        """A :class:`stepnf.plugin.shell_scales.ShellScales` for shell models (kappa, w_bar, Gamma), or ``None``."""
        return None

    def summary(self) -> str:
        """One line about the model for the run's progress report, printed once it is built (e.g. ``mesh:
        800 hex8 cells, order 2 elements (Q2), 73 000 dofs``): what the user cannot see in the scene, such as
        an element order promoted or the dof count; '' (the default): nothing to say."""
        return ""

    def describe(self) -> dict[str, Any]:
        """Facts about the model worth storing with the results (JSON-serialisable)."""
        return {"adapter": type(self).__name__, "n_dofs": int(self.n_dofs)}

    # ------------------------------------------------------ optional capability
    def eigenmodes(self, n_modes: int, *, shift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Lowest ``n_modes`` eigenpairs ``(omega**2 (m,), Phi (n, m))`` nearest ``shift``, M-normalised."""
        raise NotImplementedError(f"{type(self).__name__} does not provide eigenmodes")

    def shifted_solver(
        self, sigma: float, *, fixed_dofs: Sequence[int] | None = None
    ) -> Callable[[np.ndarray], np.ndarray]:
        """Factorise ``K - sigma M`` (with ``fixed_dofs`` held at zero) and return ``solve(b)``."""
        raise NotImplementedError(f"{type(self).__name__} does not provide shifted solves")

    def tangent_stiffness(self, u: np.ndarray) -> sp.spmatrix:
        """Tangent stiffness ``df/du`` at the displacement ``u`` (n, n), sparse."""
        raise NotImplementedError(f"{type(self).__name__} does not provide tangent stiffness")

    def quadratic_force(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Exact symmetric bilinear term ``G(u, v)`` (n,)."""
        raise NotImplementedError(f"{type(self).__name__} does not provide intrusive tensors")

    def cubic_force(self, u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Exact symmetric trilinear term ``H(u, v, w)`` (n,)."""
        raise NotImplementedError(f"{type(self).__name__} does not provide intrusive tensors")


def implements_forces(cls: type) -> bool:
    """True when ``cls`` overrides at least one of the two internal-force hooks."""
    return (
        getattr(cls, "_internal_force", None) is not SolverAdapter._internal_force
        or getattr(cls, "_internal_forces", None) is not SolverAdapter._internal_forces
    )


# ------------------------------------------------------------------------------------------------
# What every adapter returns is checked once, where it enters the core: forces in checked_forces
# (called by SolverAdapter.internal_force(s) above, and by an external solver's run where it reads
# them), K and M in checked_matrices (called by the pipeline right after asking the adapter), so
# that a new adapter cannot get a bad array past stepnf.

#: Largest relative asymmetry of K and M accepted (see :func:`stepnf.linalg.factorization.symmetry_defect`).
#: Its source is round-off: an element matrix computed in double precision is symmetric to a few
#: ulps (~1e-16 of its entries), assembling ~100 contributions per entry keeps that below ~1e-13,
#: and a solver exporting both triangles with 14 significant digits adds at most 5e-15. 1e-10
#: leaves a factor 1000 for that, while any modelling asymmetry (a wrong mass matrix, mixed-up
#: dof orders, a follower load) is at the 1e-6 .. 1 level and makes NF and DNF disagree.
SYMMETRY_TOLERANCE = 1e-10


def adapter_label(adapter: Any) -> str:
    """How messages name an adapter: its class and, when set, its registered name."""
    name = getattr(adapter, "name", "") or ""
    cls = type(adapter).__name__
    return f"solver adapter {cls}" + (f" ({name!r})" if name and name != cls else "")


def real_array(x: Any, what: str, adapter: Any) -> np.ndarray:
    """``x`` as a float64 array, or :class:`AdapterError` for complex, text or object data."""
    try:
        a = np.asarray(x)
    except Exception as exc:  # noqa: BLE001 - ragged lists and the like
        raise AdapterError(f"{adapter_label(adapter)}: its {what} are not an array: {exc}") from None
    if np.iscomplexobj(a):
        if np.any(a.imag != 0):
            raise AdapterError(f"{adapter_label(adapter)}: its {what} are complex-valued (dtype {a.dtype}, "
                               f"largest |imaginary part| {float(np.max(np.abs(a.imag))):.3g}); stepnf needs real "
                               "numbers")
        a = a.real
    if a.dtype.kind not in "biuf":
        raise AdapterError(f"{adapter_label(adapter)}: its {what} have dtype {a.dtype}; expected real numbers")
    return a.astype(float, copy=False)


def checked_forces(F: Any, m: int, adapter: Any, *, n: int | None = None, what: str = "internal forces",
                   read_from: str | None = None, fail: Callable[[str], Exception] = AdapterError) -> np.ndarray:
    """The forces ``F`` of ``m`` fields from ``adapter`` as a real float (m, n) array with finite entries: the
    one check of forces (:mod:`stepnf.step.forces`), else ``fail(message)`` (:class:`AdapterError`).

    ``what``: how a non-real ``F`` is named ("internal force": one field, whose forces may be (n,)).
    ``read_from``: the label of the external solver whose output files held ``F`` (the messages then
    say "read" and name it; ``fail`` then builds the :class:`~stepnf.errors.SolverRunError` that keeps
    the work folder and quotes the log). ``n``: the number of dofs (default ``adapter.n_dofs``).
    """
    cls = type(adapter).__name__
    n = int(adapter.n_dofs) if n is None else int(n)
    F = real_array(F, what, adapter)
    if m == 1 and what == "internal force" and F.ndim == 1:
        F = F.reshape(1, -1)
    if F.shape != (m, n):
        raise fail(f"{cls} returned forces of shape {F.shape}, expected ({m}, {n})" if read_from is None
                   else f"{cls}: read forces of shape {F.shape}, expected ({m}, {n})")
    problem = nonfinite_forces(F)
    if problem:
        raise fail(f"{cls} returned {problem}" if read_from is None else f"{read_from}: {problem}")
    return F


def nonfinite_forces(F: np.ndarray) -> str:
    """'' when every force is finite, else what is wrong (which fields, how many entries)."""
    bad = ~np.isfinite(F)
    if not bad.any():
        return ""
    rows = sorted(set(np.nonzero(bad.reshape(len(F), -1))[0].tolist()))
    return (f"NaN or inf internal forces for field(s) {rows[:10]} ({int(bad.sum())} entries); "
            "the solver probably failed to converge or diverged")


def checked_matrix(A: Any, name: str, adapter: Any, n: int | None = None) -> sp.csr_matrix:
    """The matrix ``name`` ("K", "M") an adapter returned, as real CSR, or :class:`AdapterError` saying
    what is wrong: not a matrix, complex, wrong shape, NaN/inf entries, not symmetric."""
    from stepnf.linalg.factorization import symmetry_defect

    who = adapter_label(adapter)
    n = int(adapter.n_dofs) if n is None else int(n)
    if A is None:
        raise AdapterError(f"{who}: {name} is None; expected a sparse or dense ({n}, {n}) matrix")
    if sp.issparse(A):
        A = sp.csr_matrix(A)
        data = real_array(A.data, f"{name} entries", adapter)
        A = sp.csr_matrix((data, A.indices, A.indptr), shape=A.shape)
    else:
        a = real_array(A, f"{name} entries", adapter)
        if a.ndim != 2:
            raise AdapterError(f"{who}: {name} has shape {a.shape}; expected a ({n}, {n}) matrix")
        A = sp.csr_matrix(a)
        data = A.data
    if A.shape != (n, n):
        raise AdapterError(f"{who}: {name} has shape {A.shape}; expected ({n}, {n}) for its {n} dofs")
    if n == 0:
        raise AdapterError(f"{who}: the model has no dofs ({name} is 0 x 0)")
    bad = ~np.isfinite(data)
    if bad.any():
        C = A.tocoo()
        first = int(np.nonzero(~np.isfinite(C.data))[0][0])
        raise AdapterError(f"{who}: {name} has {int(bad.sum())} NaN or inf entries, e.g. at row {int(C.row[first])}, "
                           f"column {int(C.col[first])}; the solver's assembly or its output is broken")
    d = symmetry_defect(A)
    if d > SYMMETRY_TOLERANCE:
        raise AdapterError(
            f"{who}: {name} is not symmetric: |({name} - {name}^T) x|max / |{name} x|max = {d:.3g} for a random "
            f"x (allowed {SYMMETRY_TOLERANCE:g}, the round-off of an assembly; "
            "symmetrise in the adapter if it is round-off)"
        )
    return A


def checked_matrices(adapter: Any) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """``(K, M)`` of ``adapter``, each checked once by :func:`checked_matrix` (real, (n, n), finite, symmetric)."""
    n = int(adapter.n_dofs)
    K = checked_matrix(adapter.stiffness_matrix(), "K", adapter, n)
    M = checked_matrix(adapter.mass_matrix(), "M", adapter, n)
    return K, M
