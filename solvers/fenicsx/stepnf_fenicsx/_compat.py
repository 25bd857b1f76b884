"""Every dolfinx call whose spelling changed between versions lives here (written against 0.5.2).

Newer dolfinx (0.6+) renamed ``jit_params`` to ``jit_options``,
``form_compiler_params`` to ``form_compiler_options``, moved
``VectorFunctionSpace`` to ``functionspace(mesh, ("Lagrange", k, (3,)))`` and
made ``create_mesh`` take a basix element; adapt this module only.
"""
from __future__ import annotations

import contextlib
import functools
import inspect
import io
import logging
import os
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import scipy.sparse as sp

#: meshio cell-type name -> (dolfinx cell name, geometry degree, nodes per cell)
CELLS = {
    "hexahedron27": ("hexahedron", 2, 27),
    "hexahedron": ("hexahedron", 1, 8),
    "tetra10": ("tetrahedron", 2, 10),
    "tetra": ("tetrahedron", 1, 4),
}


def cache_dir() -> Path:
    """Folder of FEniCSx's form-compilation cache, created and tested writable (a probe file).

    ``$STEPNF_CACHE_DIR/fenicsx`` when that variable is set (an :class:`OutputError`
    naming it if no file can be written there); else ``<repository>/.cache/fenicsx``
    when the adapter runs from a writable source checkout; else
    ``$XDG_CACHE_HOME/stepnf/fenicsx`` (``~/.cache/stepnf/fenicsx``); else, with one
    :class:`OutputWarning`, ``<temporary folder>/stepnf-<uid>/fenicsx`` (a read-only
    image run by a user without a writable home). Resolved once per environment.
    """
    env = os.environ.get("STEPNF_CACHE_DIR")
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return _resolve_cache(env or None, xdg, tempfile.gettempdir())


@functools.lru_cache(maxsize=None)
def _resolve_cache(env: str | None, xdg: str, tmp: str) -> Path:
    from stepnf.atomic import check_folder
    from stepnf.errors import OutputError, OutputWarning

    if env is not None:
        path = Path(env).expanduser() / "fenicsx"
        why = check_folder(path)
        if why:
            raise OutputError(f"STEPNF_CACHE_DIR={env}: the FEniCSx form cache {path} is not usable ({why}); "
                              "set STEPNF_CACHE_DIR to a writable folder or unset it", path=path)
        return path
    repo = Path(__file__).resolve().parents[3]
    if (repo / "stepnf").is_dir() and (repo / "solvers").is_dir() and not check_folder(repo / ".cache" / "fenicsx"):
        return repo / ".cache" / "fenicsx"
    home = Path(xdg).expanduser() / "stepnf" / "fenicsx"
    why_home = check_folder(home)
    if not why_home:
        return home
    uid = os.getuid() if hasattr(os, "getuid") else os.getpid()
    path = Path(tmp) / f"stepnf-{uid}" / "fenicsx"
    why = check_folder(path)
    if not why and hasattr(os, "getuid") and path.parent.stat().st_uid != uid:  # another user's folder in /tmp
        path = Path(tempfile.mkdtemp(prefix=f"stepnf-{uid}-", dir=tmp)) / "fenicsx"
        why = check_folder(path)
    if why:
        raise OutputError(f"no writable folder for the FEniCSx form cache: {why_home}; {why}; "
                          "set STEPNF_CACHE_DIR to a writable folder", path=home)
    _plain_warnings()
    warnings.warn(f"form cache: {home} not writable ({why_home}), using {path}", OutputWarning, stacklevel=3)
    return path


def comm_self():
    from mpi4py import MPI

    return MPI.COMM_SELF


def create_mesh(points: np.ndarray, cells: np.ndarray, cell_type: str, comm=None):
    """A dolfinx mesh from meshio-ordered (VTK) cells; returns ``(mesh, original_point_index)``.

    ``comm`` (default ``MPI.COMM_SELF``: a serial mesh) is the communicator the
    mesh is distributed over; every rank may pass the whole mesh, only rank 0's
    copy is used and dolfinx's graph partitioner distributes the cells.
    ``original_point_index[i]`` is the row of ``points`` that became (local)
    geometry node ``i``.
    """
    import ufl
    from dolfinx import cpp, mesh as dmesh

    if cell_type not in CELLS:
        raise ValueError(f"Unsupported cell type {cell_type!r}. Pick one of {list(CELLS)}")
    name, degree, n_nodes = CELLS[cell_type]
    ct = dmesh.CellType.hexahedron if name == "hexahedron" else dmesh.CellType.tetrahedron
    perm = np.asarray(cpp.io.perm_vtk(ct, n_nodes))
    domain = ufl.Mesh(ufl.VectorElement("Lagrange", ufl.Cell(name), degree))
    cells = np.ascontiguousarray(np.asarray(cells, dtype=np.int64)[:, perm])
    points = np.ascontiguousarray(points, dtype=float)
    with quiet_jit():
        if comm is None or comm.size == 1:
            msh = dmesh.create_mesh(comm or comm_self(), cells, points, domain)
        else:  # rank 0 hands in the mesh, the partitioner spreads the cells (no ghost cells: cell integrals only)
            if comm.rank != 0:
                cells, points = cells[:0], points[:0]
            msh = dmesh.create_mesh(comm, cells, points, domain, ghost_mode=dmesh.GhostMode.none)
    return msh, np.asarray(msh.geometry.input_global_indices, dtype=np.int64)


def vector_space(msh, degree: int):
    from dolfinx import fem

    with quiet_jit():
        return fem.VectorFunctionSpace(msh, ("Lagrange", degree))


def cell_function(msh, values: np.ndarray):
    """A piecewise-constant (DG0) function: on each cell of this process, ``values[row]`` with ``row`` the
    cell's row in the input cells of :func:`create_mesh` (``topology.original_cell_index``);
    ``values`` (input cells,) or (input cells, *shape) (a scalar or tensor field)."""
    from dolfinx import fem

    values = np.asarray(values, dtype=float)
    shape = values.shape[1:]
    with quiet_jit():
        W = fem.TensorFunctionSpace(msh, ("DG", 0), shape=shape) if shape else fem.FunctionSpace(msh, ("DG", 0))
    fn = fem.Function(W)
    im = msh.topology.index_map(msh.topology.dim)
    n = im.size_local + im.num_ghosts
    rows = np.asarray(msh.topology.original_cell_index, dtype=np.int64)[:n]
    dofs = np.asarray(W.dofmap.list.array, dtype=np.int64).reshape(n, -1)[:, 0]
    bs = int(W.dofmap.index_map_bs)
    fn.x.array.reshape(-1, bs)[dofs] = values[rows].reshape(n, bs)
    fn.x.scatter_forward()
    return fn


@contextlib.contextmanager
def quiet_jit():
    """Compile in :func:`cache_dir` without a word on the terminal.

    Forms AND elements (at mesh and function-space creation) are compiled on
    first use. Three kinds of chatter are silenced: (1) INFO lines ("running
    build_ext", the gcc command lines): the build logs through the root logger,
    to which dolfinx attached a handler, and lowers that logger's level itself
    (distutils' ``set_threshold``), so a filter on the root logger drops what is
    below WARNING, and the level is put back afterwards; (2) what gcc or a C
    library prints on the process's own stdout/stderr (file descriptors 1 and 2,
    redirected to a temporary file meanwhile; its text is attached to an
    exception raised in the block, so a failed compilation still says why);
    (3) Python warnings are kept and shown after the block. dolfinx's default
    cache folder (``~/.cache/fenics``, used for elements) is :func:`cache_dir`
    meanwhile, so a read-only home does not matter.
    """
    folder = cache_dir()  # before the redirection: its warning must reach the user
    root = logging.getLogger()
    level = root.level
    drop_info = _BelowWarning()
    root.addFilter(drop_info)
    defaults = _jit_defaults()
    saved = defaults.get("cache_dir") if defaults is not None else None
    if saved is not None:
        defaults["cache_dir"] = (folder, *saved[1:])
    try:
        with warnings.catch_warnings(record=True) as caught, _silent_fds() as captured:
            try:
                yield
            except BaseException as exc:
                text = _read_tail(captured)
                if text and hasattr(exc, "add_note"):
                    exc.add_note(f"output of the just-in-time compilation:\n{text}")
                raise
    finally:
        if saved is not None:
            defaults["cache_dir"] = saved
        root.removeFilter(drop_info)
        root.setLevel(level)
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)


@functools.lru_cache(maxsize=None)
def _plain_warnings() -> None:
    """Undo ``logging.captureWarnings(True)`` done by ``import ffcx``: it showed every warning of a
    run as ``WARNING:py.warnings:...`` through the root logger instead of stepnf's own line."""
    with contextlib.suppress(ImportError):
        import ffcx  # noqa: F401
        logging.captureWarnings(False)


def _jit_defaults() -> dict | None:
    """dolfinx's table of default JIT options (renamed in 0.6), or None."""
    try:
        from dolfinx import jit
    except ImportError:
        return None
    _plain_warnings()
    return getattr(jit, "DOLFINX_DEFAULT_JIT_PARAMETERS", None) or getattr(jit, "DOLFINX_DEFAULT_JIT_OPTIONS", None)


@contextlib.contextmanager
def _silent_fds():
    """Point file descriptors 1 and 2 to a temporary file (yielded) for the block's duration."""
    for stream in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
        with contextlib.suppress(Exception):
            stream.flush()
    try:
        sink = tempfile.TemporaryFile()
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no file descriptors to spare: chatter is better than a failure
        yield None, None
        return
    text = io.StringIO()  # what Python code prints (sys.stdout may be a wrapper that is no file descriptor)
    try:
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)
        with contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
            yield sink, text
    finally:
        for stream in (sys.__stdout__, sys.__stderr__):
            with contextlib.suppress(Exception):
                stream.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        os.close(saved[0])
        os.close(saved[1])
        sink.close()


def _read_tail(captured, limit: int = 4000) -> str:
    sink, text = captured
    if sink is None:
        return ""
    out = text.getvalue()
    with contextlib.suppress(OSError):
        sink.seek(0)
        out = sink.read().decode("utf-8", "replace") + out
    return out[-limit:].strip()


class _BelowWarning(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno >= logging.WARNING


def form(expr):
    """Compile a UFL form with the project's cache folder (:func:`cache_dir`)."""
    from dolfinx import fem

    jit = {"cache_dir": str(cache_dir()), "cffi_extra_compile_args": ["-O2"]}
    key = "jit_params" if "jit_params" in inspect.signature(fem.form).parameters else "jit_options"
    with quiet_jit():
        return fem.form(expr, **{key: jit})


def assemble_vector(compiled) -> np.ndarray:
    """Assemble a linear form into a numpy array (owned dofs, serial)."""
    from dolfinx import fem

    vec = fem.assemble_vector(compiled)
    return np.array(vec.array, copy=True)


def assemble_matrix(compiled) -> sp.csr_matrix:
    """Assemble a bilinear form into a scipy CSR matrix (serial, no boundary conditions)."""
    from dolfinx.fem import petsc

    A = petsc.assemble_matrix(compiled)
    A.assemble()
    indptr, indices, data = A.getValuesCSR()
    n = A.getSize()
    out = sp.csr_matrix((data.copy(), indices.copy(), indptr.copy()), shape=n)
    A.destroy()
    return out


def dof_layout(V) -> tuple[np.ndarray, int]:
    """Coordinates (nodes, 3) of the dof nodes of a blocked space and its block size."""
    return np.asarray(V.tabulate_dof_coordinates(), dtype=float).copy(), int(V.dofmap.index_map_bs)


def set_values(fn, values: np.ndarray) -> None:
    fn.x.array[:] = values


def comm_world():
    from mpi4py import MPI

    return MPI.COMM_WORLD


def world_size() -> int:
    """Number of MPI processes this program was started with (1 without ``mpirun``)."""
    return int(comm_world().size)


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
    vec.scatter_reverse(la.ScatterMode.add)
    return np.array(vec.array[:n_owned], copy=True)
