"""The Kratos worker process: a shell model built once, then K, M and batches of internal forces on request.

Run as ``python -m stepnf_kratos.worker`` by :class:`stepnf_kratos.client.KratosWorker`, never imported by
stepnf itself (Kratos may abort or crash the process: the parent then reports it). Protocol: pickled
requests ``(command, payload)`` on stdin, pickled replies ``("ok", result)`` or ``("error", message)`` on
the process's original stdout; everything Kratos prints goes to stderr (the parent's log file).

Commands:

``build``
    ``{"points": (N, 3), "cells": (E, k) 0-based, "element": Kratos element name, "properties": [{E, nu,
    rho, h}, ...], "cell_property": (E,) index into properties, "folder": a work folder}``: writes the
    model as an ``.mdpa`` file (:func:`write_mdpa`) and reads it with Kratos's C++ reader (no Python loop
    over nodes or elements), adds the six dofs of every node (DISPLACEMENT, ROTATION), sets up a block
    builder and reads back its equation numbers (:meth:`ShellModel._equations`, no loop over the dofs).
    Returns ``n`` (6 N).
``matrices``
    ``(K, M)`` as canonical scipy CSR (sorted column indices) in node-major order (dof ``6 i + d``, d = ux
    uy uz rx ry rz), from Kratos's elements at the undeformed state: K with the static scheme, the
    consistent M (rotational inertia included) with the eigen-solver's scheme at ``BUILD_LEVEL`` 1. Both
    are assembled into the same Kratos matrix, so they share one pattern: it is read from Kratos and
    permuted to node-major order once, and K and M share its index arrays (pickled once).
``forces``
    ``U`` (m, 6 N) -> ``F`` (m, 6 N), ``F = -RHS`` (the sign of ``K u``).
``timings``
    ``{phase: (wall, cpu)}`` seconds spent in the worker since it started (``build``, ``matrices``, and per
    force field ``reset``, ``set``, ``frames``, ``rhs``, ``copy``: the recipe's steps below), for
    ``bench/kratos.py``.

The co-rotational shells keep rotation state between calls (issue 32). Every field is therefore seen
from scratch: the scheme's step is initialised (the elements reset their stored rotations),
DISPLACEMENT and ROTATION (the *total* rotation vector) are set on every node at once
(``VariableUtils.SetSolutionStepValuesVector``), the nodes are moved to ``X0 + u``
(``UpdateCurrentPosition``), the non-linear iteration is finalised (the elements update their
co-rotational frames from those values), and the right-hand side is zeroed before it is built (it
accumulates). Skip one and the forces are wrong without any error (tests/solvers/kratos: history
independence, bit for bit). The loop over the fields is the only Python loop of a request: Kratos has no
batch of states, and one field's C++ assembly (~12 us of CPU per dof, ~36 us per DKT element) is ~96 % of
its CPU time (``bench/kratos.py``).
"""
from __future__ import annotations

import os
import pickle
import sys
import time
import traceback
from collections import defaultdict
from contextlib import contextmanager
from pathlib import Path

import numpy as np

DIRECTIONS = ("X", "Y", "Z")
#: seconds (wall, cpu) per phase of this process (the ``timings`` command)
CLOCK: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0])


@contextmanager
def clocked(phase: str):
    """Adds the wall and CPU seconds of the block to ``CLOCK[phase]`` (a few microseconds per use)."""
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        yield
    finally:
        c = CLOCK[phase]
        c[0] += time.perf_counter() - wall
        c[1] += time.process_time() - cpu


def write_mdpa(path: Path, points: np.ndarray, cells: np.ndarray, element: str, cell_property: np.ndarray,
               n_properties: int) -> None:
    """The model as a Kratos ``.mdpa`` file (1-based ids; coordinates with 17 significant digits, exact).

    Each block is formatted by one ``%`` of a repeated line format over the flattened table (C-level
    formatting; ``np.savetxt`` loops over the rows in Python)."""
    def block(fmt: str, table: np.ndarray) -> str:
        return (fmt * len(table)) % tuple(table.ravel().tolist())

    node_ids = np.arange(1, len(points) + 1, dtype=float)  # "%d" of an integral float is that integer
    with open(path, "w") as f:
        f.write("Begin ModelPartData\nEnd ModelPartData\n")
        f.write("".join(f"Begin Properties {k + 1}\nEnd Properties\n" for k in range(n_properties)))
        f.write("Begin Nodes\n")
        f.write(block("%d %.17g %.17g %.17g\n", np.column_stack([node_ids, points])))
        f.write(f"End Nodes\nBegin Elements {element}\n")
        table = np.column_stack([np.arange(1, len(cells) + 1), cell_property + 1, cells + 1])
        f.write(block("%d" + " %d" * (table.shape[1] - 1) + "\n", table))
        f.write("End Elements\n")


class ShellModel:
    """One Kratos model part of shell elements and the objects that assemble it."""

    def __init__(self, KM, SMA, request: dict):
        self.KM, self.SMA = KM, SMA
        points = np.asarray(request["points"], dtype=float)
        cells = np.asarray(request["cells"], dtype=np.int64)
        mdpa = Path(request["folder"]) / "shell"
        write_mdpa(mdpa.with_suffix(".mdpa"), points, cells, request["element"],
                   np.asarray(request["cell_property"], dtype=np.int64), len(request["properties"]))
        self.model = KM.Model()
        mp = self.mp = self.model.CreateModelPart("shell")
        for v in (KM.DISPLACEMENT, KM.ROTATION, KM.REACTION, KM.REACTION_MOMENT, KM.VELOCITY, KM.ACCELERATION,
                  KM.ANGULAR_VELOCITY, KM.ANGULAR_ACCELERATION, KM.VOLUME_ACCELERATION):
            mp.AddNodalSolutionStepVariable(v)
        mp.ProcessInfo[KM.DOMAIN_SIZE] = 3
        KM.ModelPartIO(str(mdpa)).ReadModelPart(mp)
        for k, c in enumerate(request["properties"]):
            p = mp.GetProperties()[k + 1]
            p[KM.YOUNG_MODULUS], p[KM.POISSON_RATIO] = float(c["E"]), float(c["nu"])
            p[KM.DENSITY], p[KM.THICKNESS] = float(c["rho"]), float(c["h"])
            p[KM.CONSTITUTIVE_LAW] = SMA.LinearElasticPlaneStress2DLaw()
        vu = self.vu = KM.VariableUtils()
        for c in DIRECTIONS:
            vu.AddDof(getattr(KM, "DISPLACEMENT_" + c), getattr(KM, "REACTION_" + c), mp)
        for c in DIRECTIONS:
            vu.AddDof(getattr(KM, "ROTATION_" + c), getattr(KM, "REACTION_MOMENT_" + c), mp)
        from KratosMultiphysics import python_linear_solver_factory

        # never used to solve (stepnf solves): the builder needs one
        solver = python_linear_solver_factory.ConstructSolver(KM.Parameters('{"solver_type": "skyline_lu_factorization"}'))
        self.builder = KM.ResidualBasedBlockBuilderAndSolver(solver)
        self.scheme = KM.ResidualBasedIncrementalUpdateStaticScheme()
        self.scheme.Initialize(mp)
        if not self.scheme.ElementsAreInitialized():
            self.scheme.InitializeElements(mp)
        if self.scheme.Check(mp) != 0:
            raise RuntimeError("Kratos's check of the model failed")
        self.builder.SetUpDofSet(self.scheme, mp)
        self.builder.SetUpSystem(mp)
        self.space = KM.UblasSparseSpace()
        self.A = self.space.CreateEmptyMatrixPointer()
        self.b = self.space.CreateEmptyVectorPointer()
        self.dx = self.space.CreateEmptyVectorPointer()
        self.builder.ResizeAndInitializeVectors(self.scheme, self.A, self.dx, self.b, mp)
        self.n = 6 * len(points)
        self.eq = self._equations()
        self._pattern = None  # (indices, indptr, order) of the node-major matrices (:meth:`matrices`)

    def _equations(self) -> np.ndarray:
        """Kratos's equation of each nodal dof ``6 i + d``, read without a loop over the dofs: from zero values,
        the static scheme's ``Update`` adds ``Dx[EquationId]`` to every (free) dof, so ``Dx = 0, 1, ...``
        leaves each dof holding its own equation number (exact in doubles), read node by node; the values
        are zeroed again. A dof Kratos did not number (a node without element) keeps 0: not a permutation."""
        KM, mp, vu = self.KM, self.mp, self.vu
        zeros = KM.Vector(np.zeros(3 * mp.NumberOfNodes()))
        for var in (KM.DISPLACEMENT, KM.ROTATION):
            vu.SetSolutionStepValuesVector(mp.Nodes, var, zeros, 0)
        size = self.builder.GetEquationSystemSize()
        self.scheme.Update(mp, self.builder.GetDofSet(), self.A, KM.Vector(np.arange(size, dtype=float)), self.b)
        read = [np.array(vu.GetSolutionStepValuesVector(mp.Nodes, var, 0, 3)).reshape(-1, 3)
                for var in (KM.DISPLACEMENT, KM.ROTATION)]
        for var in (KM.DISPLACEMENT, KM.ROTATION):
            vu.SetSolutionStepValuesVector(mp.Nodes, var, zeros, 0)
        eq = np.rint(np.hstack(read).ravel()).astype(np.int64)
        if size != self.n or not np.array_equal(np.sort(eq), np.arange(self.n)):
            raise RuntimeError(f"Kratos numbered {size} equations for {self.n} dofs (a node without element?)")
        return eq

    def _values(self, scheme) -> np.ndarray:
        """The entries of the matrix ``scheme`` assembles, in the node-major canonical order of :attr:`_pattern`."""
        self.space.SetToZeroMatrix(self.A)
        self.space.SetToZeroVector(self.b)
        self.builder.Build(scheme, self.mp, self.A, self.b)
        if self._pattern is None:  # Kratos's pattern, the same for every matrix assembled into A
            self._pattern = self._renumbered_pattern()
        return _array(self.A.value_data(), float)[self._pattern[2]]

    def _renumbered_pattern(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(indices, indptr, order)``: A's pattern in node-major order, sorted, and the position in Kratos's
        order of each entry (found by renumbering a matrix whose entries are 1 + their own positions)."""
        from scipy import sparse

        A, n = self.A, self.A.Size1()
        indptr = _array(A.index1_data(), np.int64)
        nnz = int(indptr[-1])
        idx = np.int32 if nnz < 2**31 else np.int64  # scipy's own choice (no copy by its constructor)
        P = sparse.csr_matrix((np.arange(1.0, nnz + 1.0), _array(A.index2_data(), idx), indptr.astype(idx)),
                              shape=(n, n))
        P = P[self.eq]
        P = P[:, self.eq].tocsr()
        P.sort_indices()
        if P.nnz != nnz:
            raise RuntimeError(f"Kratos's matrix pattern changed under the renumbering ({nnz} -> {P.nnz} entries)")
        return P.indices, P.indptr, P.data.astype(np.int64) - 1

    def matrices(self):
        from scipy import sparse

        self.state(np.zeros(self.n))
        k = self._values(self.scheme)
        self.mp.ProcessInfo[self.SMA.BUILD_LEVEL] = 1  # the mass matrix (consistent: COMPUTE_LUMPED_MASS_MATRIX unset)
        m = self._values(self.SMA.EigensolverDynamicScheme())
        self.mp.ProcessInfo[self.SMA.BUILD_LEVEL] = 2
        indices, indptr, _ = self._pattern
        K = sparse.csr_matrix((k, indices, indptr), shape=(self.n, self.n))
        M = sparse.csr_matrix((m, K.indices, K.indptr), shape=(self.n, self.n))
        M.indices, M.indptr = K.indices, K.indptr  # the same objects (not views of them): pickled once
        K.has_sorted_indices = M.has_sorted_indices = True
        return K, M

    def state(self, u: np.ndarray) -> None:
        """Put the model in the state ``u`` (6 N,) from scratch (the module docstring's recipe)."""
        KM, mp = self.KM, self.mp
        u = u.reshape(-1, 6)
        with clocked("reset"):
            self.scheme.InitializeSolutionStep(mp, self.A, self.dx, self.b)
        with clocked("set"):
            self.vu.SetSolutionStepValuesVector(mp.Nodes, KM.DISPLACEMENT, KM.Vector(np.ascontiguousarray(u[:, :3]).ravel()), 0)
            self.vu.SetSolutionStepValuesVector(mp.Nodes, KM.ROTATION, KM.Vector(np.ascontiguousarray(u[:, 3:]).ravel()), 0)
            self.vu.UpdateCurrentPosition(mp.Nodes)
        with clocked("frames"):
            self.scheme.FinalizeNonLinIteration(mp, self.A, self.dx, self.b)

    def forces(self, U: np.ndarray) -> np.ndarray:
        F = np.empty_like(U)
        for i, u in enumerate(U):  # one C++ assembly per field (Kratos has no batch of states)
            self.state(u)
            with clocked("rhs"):
                self.space.SetToZeroVector(self.b)
                self.builder.BuildRHS(self.scheme, self.mp, self.b)
            with clocked("copy"):
                F[i] = -np.array(self.b)[self.eq]
        return F


def _array(values: list, dtype) -> np.ndarray:
    """``values`` (a list: Kratos's CompressedMatrix has no buffer) as an array; the list is freed by the caller
    at once (a list of 4 million numbers holds ~150 MB)."""
    return np.fromiter(values, dtype, count=len(values))


def main() -> int:
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # Kratos's banner and log lines go to stderr, the parent's log file
    inp = sys.stdin.buffer
    import KratosMultiphysics as KM
    import KratosMultiphysics.StructuralMechanicsApplication as SMA

    KM.Logger.GetDefaultOutput().SetSeverity(KM.Logger.Severity.WARNING)
    model = None
    while True:
        try:
            command, payload = pickle.load(inp)
        except EOFError:
            return 0
        try:
            if command == "quit":
                return 0
            if command == "timings":
                result = {k: tuple(v) for k, v in CLOCK.items()}
            elif command == "build":
                with clocked("build"):
                    model = ShellModel(KM, SMA, payload)
                result = model.n
            elif model is None:
                raise RuntimeError(f"{command!r} before build")
            elif command == "matrices":
                with clocked("matrices"):
                    result = model.matrices()
            elif command == "forces":
                result = model.forces(np.asarray(payload, dtype=float))
            else:
                raise RuntimeError(f"unknown command {command!r}")
            reply = ("ok", result)
        except Exception as exc:  # noqa: BLE001 - every failure goes back to the parent as a message
            traceback.print_exc()
            reply = ("error", f"{type(exc).__name__}: {exc}")
        pickle.dump(reply, out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()


if __name__ == "__main__":
    sys.exit(main())
