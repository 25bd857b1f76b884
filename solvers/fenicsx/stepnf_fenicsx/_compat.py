"""Every dolfinx call whose spelling changed between versions lives here.

Supported: DOLFINx 0.5 (Debian 12) and 0.9 (Debian 13), both tested; 0.8 and
0.10 are written from their documented API (the differences to 0.9 are
small). What moved, and how this module tells the versions apart (by feature,
not by version number, so an intermediate release takes the right branch):

* coordinate element of a mesh: ``ufl.VectorElement`` (0.5, 0.6) ->
  ``basix.ufl.element(..., shape=(gdim,))`` (0.7+): whether ``basix.ufl`` exists;
* ``create_mesh(comm, cells, x, domain, ghost_mode=...)`` (0.5, 0.6) ->
  ``create_mesh(comm, cells, x, e, partitioner=...)`` (0.7-0.10; later
  releases swap ``x`` and ``e``): the parameter names, passed by keyword;
* ``VectorFunctionSpace``/``FunctionSpace``/``TensorFunctionSpace`` ->
  ``functionspace(mesh, (family, degree, shape))`` (0.7+);
* dofmaps: ``AdjacencyList`` (``.array``) -> 2D numpy arrays (0.7+);
  ``topology.original_cell_index``: one array -> a list per cell type (0.10);
* ``jit_params`` -> ``jit_options`` (0.6+), ``DOLFINX_DEFAULT_JIT_PARAMETERS``
  -> ``DOLFINX_DEFAULT_JIT_OPTIONS``;
* ``Expression.eval(cells)`` -> ``Expression.eval(mesh, cells)`` (0.8+);
* ``la.ScatterMode`` -> ``la.InsertMode`` (0.7+);
* the element degree: ``ufl_element().degree()`` -> a property (basix.ufl).

Every other module of the adapter calls these, never the spellings above.
"""
from __future__ import annotations

import contextlib
import inspect
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from . import jitcache

#: meshio cell-type name -> (dolfinx cell name, geometry degree, nodes per cell)
CELLS = {
    "hexahedron27": ("hexahedron", 2, 27),
    "hexahedron": ("hexahedron", 1, 8),
    "tetra10": ("tetrahedron", 2, 10),
    "tetra": ("tetrahedron", 1, 4),
    "triangle6": ("triangle", 2, 6),
}


def cache_dir() -> Path:
    """Folder of FEniCSx's form-compilation cache (:func:`stepnf_fenicsx.jitcache.cache_dir`)."""
    return jitcache.cache_dir()


@contextlib.contextmanager
def quiet_jit():
    """Compile in :func:`cache_dir` without a word on the terminal (:func:`stepnf_fenicsx.jitcache.quiet_jit`)."""
    with jitcache.quiet_jit(jit_defaults()):
        yield


def jit_defaults() -> dict | None:
    """dolfinx's table of default JIT options (renamed in 0.6), or None."""
    try:
        from dolfinx import jit
    except ImportError:
        return None
    jitcache.plain_warnings()
    return getattr(jit, "DOLFINX_DEFAULT_JIT_PARAMETERS", None) or getattr(jit, "DOLFINX_DEFAULT_JIT_OPTIONS", None)


def jit_keyword(fn) -> str:
    """The name of the JIT options argument of ``fn`` (``fem.form``, ``fem.Expression``)."""
    return "jit_params" if "jit_params" in inspect.signature(fn).parameters else "jit_options"


def _jit_options() -> dict:
    return {"cache_dir": str(cache_dir()), "cffi_extra_compile_args": ["-O2"]}


# ------------------------------------------------------------ MPI
def comm_self():
    from mpi4py import MPI

    return MPI.COMM_SELF


def comm_world():
    from mpi4py import MPI

    return MPI.COMM_WORLD


def world_size() -> int:
    """Number of MPI processes this program was started with (1 without ``mpirun``)."""
    return int(comm_world().size)


# ------------------------------------------------------------ meshes
def coordinate_domain(cell: str, degree: int, gdim: int):
    """The ``ufl.Mesh`` of a Lagrange geometry of ``degree`` on ``cell`` in ``gdim`` dimensions."""
    import ufl

    try:
        import basix.ufl
    except ImportError:  # dolfinx 0.5, 0.6
        return ufl.Mesh(ufl.VectorElement("Lagrange", ufl.Cell(cell), degree, dim=gdim))
    return ufl.Mesh(basix.ufl.element("Lagrange", cell, degree, shape=(gdim,)))


def create_mesh(points: np.ndarray, cells: np.ndarray, cell_type: str, comm=None):
    """A dolfinx mesh from meshio-ordered (VTK) cells; returns ``(mesh, original_point_index)``.

    ``cell_type`` one of :data:`CELLS` (the solids' cells, and ``triangle6``
    for the shallow shell's plan view; the geometric dimension is
    ``points.shape[1]``). ``comm`` (default ``MPI.COMM_SELF``: a serial mesh)
    is the communicator the mesh is distributed over; every rank may pass the
    whole mesh, only rank 0's copy is used and dolfinx's graph partitioner
    distributes the cells (no ghost cells: cell integrals only).
    ``original_point_index[i]`` is the row of ``points`` that became (local)
    geometry node ``i``.
    """
    from dolfinx import cpp, mesh as dmesh

    if cell_type not in CELLS:
        raise ValueError(f"Unsupported cell type {cell_type!r}. Pick one of {list(CELLS)}")
    name, degree, n_nodes = CELLS[cell_type]
    perm = np.asarray(cpp.io.perm_vtk(getattr(dmesh.CellType, name), n_nodes))
    points = np.ascontiguousarray(points, dtype=float)
    domain = coordinate_domain(name, degree, points.shape[1])
    cells = np.ascontiguousarray(np.asarray(cells, dtype=np.int64)[:, perm])
    comm = comm or comm_self()
    distributed = comm.size > 1
    if distributed and comm.rank != 0:  # rank 0 hands in the mesh, the partitioner spreads the cells
        cells, points = cells[:0], points[:0]
    params = inspect.signature(dmesh.create_mesh).parameters
    if "domain" in params:  # 0.5, 0.6
        extra = {"domain": domain}
        if distributed:
            extra["ghost_mode"] = dmesh.GhostMode.none
    else:
        extra = {"e": domain}
        if distributed:
            extra["partitioner"] = dmesh.create_cell_partitioner(dmesh.GhostMode.none)
    with quiet_jit():
        msh = dmesh.create_mesh(comm, cells=cells, x=points, **extra)
    return msh, np.asarray(msh.geometry.input_global_indices, dtype=np.int64)


def original_cell_index(msh) -> np.ndarray:
    """For each local cell (owned, then ghost), its row in the cells given to :func:`create_mesh`."""
    index = msh.topology.original_cell_index
    if isinstance(index, (list, tuple)):  # 0.10: one array per cell type
        index = index[0]
    return np.asarray(index, dtype=np.int64)


def cell_name(msh) -> str:
    """The cell type's name (``"hexahedron"``, ``"triangle"``, ...)."""
    topology = msh.topology
    return topology.cell_name() if hasattr(topology, "cell_name") else topology.cell_type.name


def geometry_dofmap(msh) -> np.ndarray:
    """``(local cells, geometry nodes per cell)``: the geometry nodes of each cell."""
    dofmap = msh.geometry.dofmap
    if hasattr(dofmap, "array"):  # AdjacencyList (0.5, 0.6)
        return np.asarray(dofmap.array).reshape(-1, dofmap.offsets[1] - dofmap.offsets[0])
    return np.asarray(dofmap).reshape(len(dofmap), -1)


def num_cells(msh) -> int:
    """Number of cells this process owns."""
    return int(msh.topology.index_map(msh.topology.dim).size_local)


# ------------------------------------------------------------ spaces and functions
def vector_space(msh, degree: int, dim: int | None = None):
    """Lagrange space of ``degree`` with ``dim`` components (default: the mesh's geometric dimension)."""
    from dolfinx import fem

    dim = int(msh.geometry.x.shape[1] if dim is None else dim)
    with quiet_jit():
        if hasattr(fem, "functionspace"):
            return fem.functionspace(msh, ("Lagrange", int(degree), (dim,)))
        return fem.VectorFunctionSpace(msh, ("Lagrange", int(degree)), dim=dim)


def scalar_space(msh, family: str, degree: int, shape: tuple[int, ...] = ()):
    """Space of scalar (``shape = ()``) or tensor-valued functions of ``family`` (``"Lagrange"``, ``"DG"``)."""
    from dolfinx import fem

    with quiet_jit():
        if hasattr(fem, "functionspace"):
            return fem.functionspace(msh, (family, int(degree), tuple(shape)) if shape else (family, int(degree)))
        if shape:
            return fem.TensorFunctionSpace(msh, (family, int(degree)), shape=tuple(shape))
        return fem.FunctionSpace(msh, (family, int(degree)))


def cell_dofmap(V) -> np.ndarray:
    """``(local cells, dofs per cell)``: the dof nodes (blocks) of each cell of this process."""
    dofs = V.dofmap.list
    if hasattr(dofs, "array"):  # AdjacencyList (0.5, 0.6)
        return np.asarray(dofs.array, dtype=np.int64).reshape(-1, dofs.offsets[1] - dofs.offsets[0])
    return np.asarray(dofs, dtype=np.int64).reshape(len(dofs), -1)


def element_degree(V) -> int:
    """Polynomial degree of the element of ``V``."""
    degree = V.ufl_element().degree
    return int(degree() if callable(degree) else degree)


def constant(msh, value):
    """A ``fem.Constant`` holding a float or a float array."""
    from dolfinx import fem

    value = np.asarray(value, dtype=float)
    return fem.Constant(msh, float(value) if value.ndim == 0 else value)


def cell_function(msh, values: np.ndarray):
    """A piecewise-constant (DG0) function: on each cell of this process, ``values[row]`` with ``row`` the
    cell's row in the input cells of :func:`create_mesh` (:func:`original_cell_index`);
    ``values`` (input cells,) or (input cells, *shape) (a scalar or tensor field)."""
    from dolfinx import fem

    values = np.asarray(values, dtype=float)
    shape = values.shape[1:]
    W = scalar_space(msh, "DG", 0, shape)
    fn = fem.Function(W)
    im = msh.topology.index_map(msh.topology.dim)
    n = im.size_local + im.num_ghosts
    rows = original_cell_index(msh)[:n]
    dofs = cell_dofmap(W)[:n, 0]
    bs = int(W.dofmap.index_map_bs)
    fn.x.array.reshape(-1, bs)[dofs] = values[rows].reshape(n, bs)
    fn.x.scatter_forward()
    return fn


def expression(expr, points: np.ndarray):
    """A compiled ``fem.Expression`` of ``expr`` at reference ``points`` (k, tdim) of a cell."""
    from dolfinx import fem

    with quiet_jit():
        return fem.Expression(expr, np.ascontiguousarray(points, dtype=float),
                              **{jit_keyword(fem.Expression.__init__): _jit_options()})


def evaluate(compiled, msh, cells: np.ndarray) -> np.ndarray:
    """``(len(cells), points * value size)``: a compiled :func:`expression` on local ``cells``."""
    cells = np.asarray(cells, dtype=np.int32)
    if "mesh" in inspect.signature(compiled.eval).parameters:  # 0.8+
        out = compiled.eval(msh, cells)
    else:
        out = compiled.eval(cells)
    return np.asarray(out).reshape(len(cells), -1)


def form(expr):
    """Compile a UFL form with the project's cache folder (:func:`cache_dir`)."""
    from dolfinx import fem

    with quiet_jit():
        return fem.form(expr, **{jit_keyword(fem.form): _jit_options()})


def assemble_vector(compiled) -> np.ndarray:
    """Assemble a linear form into a numpy array (owned dofs, serial)."""
    from dolfinx import fem

    vec = fem.assemble_vector(compiled)
    return np.array(vec.array, copy=True)


def assemble_matrix(compiled, pattern: tuple[np.ndarray, np.ndarray] | None = None) -> sp.csr_matrix:
    """Assemble a bilinear form into a scipy CSR matrix (serial, no boundary conditions).

    With ``pattern`` (``(indptr, indices)`` of this form's matrix: :func:`expand_pattern` of its
    :func:`sparsity_graph`, possibly shared with another form of the same graph) the form is assembled
    straight into a new value array on it: a PETSc matrix on our arrays (``MatCreateSeqAIJWithArrays``),
    nothing copied out of PETSc afterwards (0.4 s per matrix at 250k dofs). The pattern must be the
    form's own: DOLFINx's release build drops an entry outside it without an error. Without ``pattern``
    DOLFINx assembles into its own PETSc matrix, copied (:func:`csr_copy`). Either way the values are
    those of DOLFINx's assembly, bit for bit (the same sums in the same order).
    """
    from dolfinx.fem import petsc

    if pattern is not None:
        return _assemble_on(compiled, pattern)
    A = petsc.assemble_matrix(compiled)
    A.assemble()
    try:
        return csr_copy(A)
    finally:
        A.destroy()


def sparsity_graph(compiled) -> tuple[int, np.ndarray, np.ndarray] | None:
    """``(bs, offsets, columns)``: DOLFINx's sparsity pattern of a bilinear form of one blocked space, by
    nodes (``bs x bs`` blocks of dofs). None for two different spaces or a sparsity API this does not know.

    0.5: ``pattern.assemble()``, ``pattern.graph`` an AdjacencyList (``.offsets``, ``.array``); 0.9:
    ``pattern.finalize()``, ``pattern.graph`` the tuple ``(links, offsets)``."""
    from dolfinx import fem

    V0, V1 = compiled.function_spaces
    if V1 is not V0:
        return None
    try:
        pattern = fem.create_sparsity_pattern(compiled)
        finish = getattr(pattern, "finalize", None) or pattern.assemble
        finish()
        graph = pattern.graph
        columns, offsets = graph if isinstance(graph, tuple) else (graph.array, graph.offsets)
    except (AttributeError, TypeError, ValueError):
        return None
    return int(V0.dofmap.index_map_bs), np.array(offsets), np.array(columns)


def expand_pattern(graph: tuple[int, np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(indptr, indices)`` (PETSc's integer type) of the dofs of a node graph (:func:`sparsity_graph`):
    each node entry a ``bs x bs`` block, columns sorted in each row (PETSc's layout of the matrix)."""
    from petsc4py import PETSc

    bs, offsets, columns = graph
    nb = len(offsets) - 1
    ones = np.ones((len(columns), bs, bs), dtype=np.int8)  # scipy expands the node pattern into dofs
    scalar = sp.bsr_matrix((ones, columns, offsets), shape=(nb * bs, nb * bs)).tocsr()
    scalar.sort_indices()
    itype = PETSc.IntType
    return scalar.indptr.astype(itype, copy=False), scalar.indices.astype(itype, copy=False)


def _assemble_on(compiled, pattern: tuple[np.ndarray, np.ndarray]) -> sp.csr_matrix:
    """The form assembled into a new value array on ``pattern`` (see :func:`assemble_matrix`)."""
    from dolfinx.fem import petsc
    from petsc4py import PETSc

    indptr, indices = pattern
    n = len(indptr) - 1
    V = compiled.function_spaces[0]
    bs = int(V.dofmap.index_map_bs)
    data = np.zeros(len(indices))
    B = PETSc.Mat().createAIJWithArrays((n, n), (indptr, indices, data), comm=PETSc.COMM_SELF)
    B.setBlockSize(bs)  # DOLFINx inserts node blocks (MatSetValuesBlockedLocal); petsc4py ignores bsize= here
    lgmap = PETSc.LGMap().create(np.arange(n // bs, dtype=PETSc.IntType), bsize=bs, comm=PETSc.COMM_SELF)
    try:
        B.setLGMap(lgmap, lgmap)  # serial: local numbering is global
        # never a new entry: PETSc would move the values out of our array into its own
        B.setOption(PETSc.Mat.Option.NEW_NONZERO_LOCATION_ERR, True)
        petsc.assemble_matrix(B, compiled)
        B.assemble()
    finally:
        B.destroy()
        lgmap.destroy()
    return sp.csr_matrix((data, indices, indptr), shape=(n, n), copy=False)


def csr_copy(A) -> sp.csr_matrix:
    """A scipy CSR copy of a sequential PETSc AIJ matrix: its index arrays (``MatGetRowIJ``) and its
    values copied in one piece (``MatCopy`` into a matrix on our own array, same pattern).

    ``getValuesCSR`` reads the rows one by one: 0.7 s per matrix at 250k dofs (36M entries), against
    0.07 s here; the result is the same, bit for bit.
    """
    from petsc4py import PETSc

    indptr, indices = A.getRowIJ()
    data = np.empty(len(indices))
    B = PETSc.Mat().createAIJWithArrays(A.getSize(), (indptr, indices, data), comm=PETSc.COMM_SELF)
    try:
        A.copy(B, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
    finally:
        B.destroy()
    return sp.csr_matrix((data, indices, indptr), shape=A.getSize(), copy=False)


def dof_layout(V) -> tuple[np.ndarray, int]:
    """Coordinates (nodes, 3) of the dof nodes of a blocked space and its block size."""
    return np.asarray(V.tabulate_dof_coordinates(), dtype=float).copy(), int(V.dofmap.index_map_bs)


def set_values(fn, values: np.ndarray) -> None:
    fn.x.array[:] = values


def assemble_petsc_matrix(compiled):
    """Assemble a bilinear form into a (distributed) PETSc matrix, no boundary conditions; caller owns it."""
    from dolfinx.fem import petsc

    A = petsc.assemble_matrix(compiled)
    A.assemble()
    return A


def assemble_owned(compiled, n_owned: int) -> np.ndarray:
    """Assemble a linear form over a distributed mesh: ghost contributions added to their owners.

    Returns the ``n_owned`` owned entries (``index_map.size_local * bs``, first in the local array).
    """
    from dolfinx import fem, la

    vec = fem.assemble_vector(compiled)
    vec.scatter_reverse(la.InsertMode.add if hasattr(la, "InsertMode") else la.ScatterMode.add)
    return np.array(vec.array[:n_owned], copy=True)
