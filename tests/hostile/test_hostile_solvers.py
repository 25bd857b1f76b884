"""Hostile solver output: bad K, M, tangents or forces from any adapter, and corrupted CalculiX result files.

What an adapter returns is checked once where it enters the core
(:func:`stepnf.plugin.adapter.checked_matrices` for K and M, ``internal_force(s)`` for
forces, :mod:`stepnf.step.procedure` for tangents): each case ends with exit 3 and a
message naming the adapter and what is wrong. Result files of external
solvers are checked where they are read: the message names the file, the
work folder (kept) and quotes the end of the solver log.
"""
from __future__ import annotations

import shutil
import stat
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from helpers.hostile import assert_reported, run_cli
from helpers.required import requires
from stepnf.plugin.adapter import SYMMETRY_TOLERANCE, checked_matrix
from stepnf.errors import AdapterError
from stepnf.external import ExternalSolverAdapter, require_files
from stepnf_polynomial import PolynomialAdapter, save_system
from helpers.systems import random_system, use_solver

N = 6


def scene(tmp_path, extra=""):
    M, K, G, H = random_system(N, seed=8)
    save_system(tmp_path / "s.npz", M, K, G, H)
    p = tmp_path / "s.toml"
    p.write_text('[model]\nsolver = "polynomial"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0]\n'
                 f'methods = ["nf", "dnf"]\n{extra}[output]\ndir = "out"\nplot = false\n')
    return p


def _asym(A):
    B = np.array(A, dtype=float)
    B[0, 1] += 3e-2 * np.abs(B).max()
    return B


# each: (what mass_matrix / stiffness_matrix return instead, given the good M and K) -> (matrix, mentions)
BAD_MATRICES = {
    "M_not_symmetric": ("M", lambda A: _asym(A), ["M is not symmetric", "allowed 1e-10"]),
    "K_not_symmetric": ("K", lambda A: _asym(A), ["K is not symmetric"]),
    "K_nan": ("K", lambda A: np.where(np.eye(N, dtype=bool) & (np.arange(N) == 2), np.nan, A), ["K", "NaN", "row 2"]),
    "M_inf": ("M", lambda A: sp.csr_matrix(np.where(np.arange(N)[:, None] == 4, np.inf, A)), ["M", "inf"]),
    "K_complex": ("K", lambda A: A + 1e-3j * np.eye(N), ["complex"]),
    "M_complex_sparse": ("M", lambda A: sp.csr_matrix(A + 1j * np.eye(N)), ["complex"]),
    "K_short": ("K", lambda A: A[:-1], ["K has shape (5, 6)", f"({N}, {N})"]),
    "M_wide": ("M", lambda A: sp.csr_matrix(np.hstack([A, A])), ["M has shape"]),
    "K_vector": ("K", lambda A: np.diag(A), ["K has shape (6,)"]),
    "M_scalar": ("M", lambda A: np.float64(1.0), ["M has shape ()"]),
    "K_strings": ("K", lambda A: A.astype(str), ["dtype"]),
    "M_objects": ("M", lambda A: np.array([[object()] * N] * N), ["dtype object"]),
    "K_none": ("K", lambda A: None, ["K is None"]),
    "M_ragged": ("M", lambda A: [[1.0, 2.0], [3.0]], ["M"]),
}


def _bad_adapter(which: str, make):
    class BadMatrix(PolynomialAdapter):
        def mass_matrix(self):
            return make(self._M) if which == "M" else super().mass_matrix()

        def stiffness_matrix(self):
            return make(self._K) if which == "K" else super().stiffness_matrix()

    return BadMatrix


@pytest.mark.parametrize("case", list(BAD_MATRICES))
def test_bad_matrices_are_solver_failures(tmp_path, capsys, monkeypatch, case):
    which, make, mentions = BAD_MATRICES[case]
    use_solver(monkeypatch, lambda name: _bad_adapter(which, make))
    o = run_cli(["run", scene(tmp_path), "-q"], capsys)
    assert_reported(o, codes=(3,), mentions=["BadMatrix", "polynomial", *mentions])
    assert not (tmp_path / "out" / "s.h5").exists()


@pytest.mark.parametrize("make", [
    lambda A: A + 1e-14 * np.abs(A).max() * np.triu(np.ones_like(A), 1),  # round-off asymmetry
    lambda A: A.astype(complex),                                          # complex dtype, zero imaginary part
    lambda A: sp.coo_matrix(A),                                           # any sparse format
    lambda A: A.astype(np.float32).astype(float),                         # symmetric, fewer digits
], ids=["roundoff", "complex_zero_imag", "coo", "float32"])
def test_acceptable_matrices_pass(tmp_path, capsys, monkeypatch, make):
    use_solver(monkeypatch, lambda name: _bad_adapter("K", make))
    o = run_cli(["run", scene(tmp_path), "-q", "--no-hdf5"], capsys)
    assert o.code == 0, o.err


def test_non_symmetric_mass_in_a_polynomial_file(tmp_path, capsys):
    """The polynomial adapter takes its arrays from the file: a non-symmetric M used to give NF != DNF."""
    p = scene(tmp_path)  # writes the good system: replaced by one with a non-symmetric M
    M, K, G, H = random_system(N, seed=8)
    save_system(tmp_path / "s.npz", _asym(M), K, G, H)
    o = run_cli(["run", p, "-q"], capsys)
    assert_reported(o, codes=(3,), mentions=["PolynomialAdapter", "M is not symmetric"])


def test_symmetry_check_is_cheap_and_exact_enough():
    """The probe sees an asymmetry of relative size d as ~d and round-off as round-off; ~0.1 s at 100k dofs."""
    import time

    from stepnf.linalg.factorization import symmetry_defect

    rng = np.random.default_rng(1)
    n = 100_000
    offs = np.arange(-40, 41) * 17
    A = sp.diags([rng.standard_normal(n - abs(o)) for o in offs], offs, format="csr")
    A = (A + A.T).tocsr()
    t0 = time.perf_counter()
    assert symmetry_defect(A) == 0.0
    assert time.perf_counter() - t0 < 2.0
    B = A.copy()
    B.data[::1000] *= 1 + 1e-3
    assert 1e-7 < symmetry_defect(B) < 1e-2
    C = A.copy()
    C.data *= 1 + 1e-16 * rng.standard_normal(C.nnz)
    assert symmetry_defect(C) < SYMMETRY_TOLERANCE


def test_checked_matrix_direct():
    class Named:
        name = "mine"
        n_dofs = 2

    with pytest.raises(AdapterError, match=r"Named \('mine'\): K is not symmetric"):
        checked_matrix(np.array([[1.0, 2.0], [0.0, 1.0]]), "K", Named())
    with pytest.raises(AdapterError, match="no dofs"):
        checked_matrix(np.zeros((0, 0)), "K", Named(), 0)


# ------------------------------------------------------------------------------------ forces, tangents
def _bad_forces(make):
    class BadForces(PolynomialAdapter):
        def _internal_forces(self, U):
            return make(super()._internal_forces(U))

    return BadForces


@pytest.mark.parametrize("make, mentions", [
    (lambda F: np.where(np.arange(F.shape[1]) == 1, np.nan, F), ["NaN or inf internal forces", "field(s) [0"]),
    (lambda F: F * np.inf, ["NaN or inf"]),
    (lambda F: F + 1e-3j, ["complex"]),
    (lambda F: F[:, :-1], ["shape"]),
    (lambda F: F.astype(str), ["dtype"]),
    (lambda F: [list(r) for r in F[:, :-1]] + [[1.0]], ["forces"]),
], ids=["nan", "inf", "complex", "shape", "strings", "ragged"])
def test_bad_forces_are_solver_failures(tmp_path, capsys, monkeypatch, make, mentions):
    use_solver(monkeypatch, lambda name: _bad_forces(make))
    o = run_cli(["run", scene(tmp_path), "-q"], capsys)
    assert_reported(o, codes=(3,), mentions=["BadForces", *mentions])


@pytest.mark.parametrize("make, mentions", [
    (lambda T: T.toarray() * np.nan, ["K_T", "NaN"]),
    (lambda T: sp.csr_matrix(_asym(T.toarray())), ["K_T is not symmetric"]),
    (lambda T: T[:-1], ["K_T has shape"]),
], ids=["nan", "asymmetric", "shape"])
def test_bad_tangent_stiffness(tmp_path, capsys, monkeypatch, make, mentions):
    class BadTangent(PolynomialAdapter):
        def tangent_stiffness(self, u):
            return make(super().tangent_stiffness(u))

    use_solver(monkeypatch, lambda name: BadTangent)
    o = run_cli(["run", scene(tmp_path, '[analysis.step]\nmethod = "tangent"\n'), "-q"], capsys)
    assert_reported(o, codes=(3,), mentions=["BadTangent", *mentions])


# ----------------------------------------------------------------------- any external solver: its files
FAKE = textwrap.dedent("""
    import sys
    import numpy as np
    mode = sys.argv[1]
    print("FAKE-SOLVER-LOG: mode", mode, flush=True)
    U = np.atleast_2d(np.loadtxt("fields.txt"))
    F = U * np.array([1.0, 2.0, 3.0, 5.0]) + U ** 3
    text = "\\n".join(" ".join("%.17e" % v for v in row) for row in F) + "\\n"
    if mode == "nan":
        text = text.replace(text.split()[1], "nan", 1)
    elif mode == "garbage":
        text = "Segmentation fault?\\n" + text
    elif mode == "truncated":
        text = text[: len(text) // 2]
    elif mode == "binary":
        text = "\\x00\\x01\\x02" * 40
    with open("forces.txt", "w") as f:
        f.write(text)
    print("FAKE-SOLVER-LOG: done", flush=True)
""")


class FileSolver(ExternalSolverAdapter):
    """f(u) = diag(1, 2, 3, 5) u + u**3 computed by a script that can corrupt its output file."""

    name = "filesolver"
    program = sys.executable

    def __init__(self, mode: str = "ok", **kw):
        kw["workdir"] = Path(kw["workdir"]) if "workdir" in kw else None
        super().__init__(**kw)
        self.mode = mode

    @property
    def n_dofs(self):
        return 4

    def mass_matrix(self):
        return sp.identity(4, format="csr")

    def stiffness_matrix(self):
        return sp.diags([1.0, 2.0, 3.0, 5.0], format="csr")

    def write_force_job(self, workdir, U):
        np.savetxt(workdir / "fields.txt", U, fmt="%.17e")
        (workdir / "fake.py").write_text(FAKE)
        return [self.program, "fake.py", self.mode]

    def read_forces(self, workdir, m):
        (path,) = require_files(workdir, ["forces.txt"], log=workdir / "solver.log")
        return np.atleast_2d(np.loadtxt(path)).reshape(m, -1)


@pytest.mark.parametrize("mode, mentions", [
    ("nan", ["NaN or inf internal forces"]),
    ("garbage", ["cannot read the forces"]),
    ("truncated", ["forces"]),
    ("binary", ["cannot read the forces"]),
])
def test_external_solver_bad_output_keeps_folder_and_quotes_log(tmp_path, capsys, monkeypatch, mode, mentions):
    use_solver(monkeypatch, lambda name: FileSolver)
    work = tmp_path / "work"
    s = tmp_path / "f.toml"
    s.write_text(f'[model]\nsolver = "filesolver"\nmode = "{mode}"\nworkdir = "{work}"\n[analysis]\n'
                 'master_modes = [0]\nmethods = ["nf"]\n[output]\ndir = "out"\nplot = false\n')
    o = run_cli(["run", s, "-q"], capsys)
    assert_reported(o, codes=(3,), mentions=["work folder", "end of the solver log", "FAKE-SOLVER-LOG", *mentions])
    kept = [p for p in work.iterdir() if (p / "forces.txt").is_file()]
    assert kept, "the work folder of the failed run was removed"


# ------------------------------------------------------------------------------ CalculiX result files
CCX = shutil.which("ccx")

CORRUPT = textwrap.dedent("""
    import math, os, sys
    from pathlib import Path
    job, action, target = sys.argv[1], sys.argv[2], sys.argv[3]
    if not Path(target).name.startswith(job + "."):
        sys.exit(0)  # another run (matrices or forces) than the one to corrupt
    p = Path(target)
    if action == "missing":
        p.unlink()
        sys.exit(0)
    text = p.read_text(errors="replace")
    lines = text.splitlines(keepends=True)
    if action == "garbage":
        text = "this is not a result file\\n" * 5
    elif action == "midgarbage":
        k = len(lines) // 2
        text = "".join(lines[:k]) + "   ### garbage ###   \\n" + "".join(lines[k:])
    elif action == "truncate_line":
        text = text[: len(text) // 2 + 3]
    elif action == "truncate_rows":
        text = "".join(lines[: len(lines) // 2])
    elif action == "empty":
        text = ""
    elif action == "nan":
        k = len(lines) - 2
        parts = lines[k].split()
        parts[-1] = "NaN"
        lines[k] = "   ".join(parts) + "\\n"
        text = "".join(lines)
    elif action == "badtime":
        import re
        text = re.sub(r"(and time)\\s+\\S+", r"\\1 garbled", text, count=1)
    p.write_text(text)
""")


def _fake_ccx(tmp_path, action, target):
    """``ccx`` that runs the real one, then corrupts ``target`` (one output file) and logs a marker."""
    (tmp_path / "corrupt.py").write_text(CORRUPT)
    exe = tmp_path / "fake_ccx"
    exe.write_text(f'#!/bin/sh\n"{CCX}" "$@" || exit $?\necho "FAKE-CCX: corrupting {target}"\n'
                   f'"{sys.executable}" "{tmp_path / "corrupt.py"}" "$2" {action} {target}\n')
    exe.chmod(exe.stat().st_mode | stat.S_IEXEC)
    return exe


def _ccx_scene(tmp_path, exe):
    from stepnf_calculix.deck import mesh_text

    from helpers.meshes import hex20_block

    p, c = hex20_block(2, 2, 1)
    ids = np.arange(1, len(p) + 1)
    (tmp_path / "part.inp").write_text(mesh_text(ids, p, [("C3D20", np.arange(1, len(c) + 1), ids[c])]))
    s = tmp_path / "c.toml"
    s.write_text(f'[model]\nsolver = "calculix"\nmesh = "part.inp"\nexecutable = "{exe}"\nworkdir = "work"\n'
                 '[model.material]\nE = 2.0e11\nnu = 0.3\nrho = 7800.0\n[analysis]\nmaster_modes = [0]\n'
                 'methods = ["nf"]\nretained_modes = 4\n[output]\ndir = "out"\nplot = false\n')
    return s


CCX_CASES = [
    (a, t) for t in ("matrices.sti", "matrices.mas", "matrices.dof")
    for a in ("garbage", "midgarbage", "truncate_line", "truncate_rows", "empty", "nan", "missing")
    if not (t.endswith(".dof") and a == "nan")
] + [(a, "forces.dat") for a in ("garbage", "midgarbage", "truncate_line", "truncate_rows", "empty", "nan",
                                  "missing", "badtime")]


@pytest.mark.calculix
@requires("ccx")
@pytest.mark.parametrize("action, target", CCX_CASES, ids=[f"{t}-{a}" for a, t in CCX_CASES])
def test_calculix_corrupt_results(tmp_path, capsys, action, target):
    pytest.importorskip("stepnf_calculix")
    exe = _fake_ccx(tmp_path, action, target)
    o = run_cli(["run", _ccx_scene(tmp_path, exe), "-q", "--allow-programs"], capsys)  # the scene names fake_ccx
    assert_reported(o, codes=(3,), mentions=["work folder", "FAKE-CCX: corrupting"])
    stem = target.split(".")[0]
    assert target in o.err or f"{stem}." in o.err, o.err
    folders = [p for p in (tmp_path / "work").iterdir() if p.name.startswith(f"calculix-{stem}-")]
    assert folders and any((p / "solver.log").is_file() for p in folders), "work folder not kept"
    assert not (tmp_path / "out" / "c.h5").exists()


# ------------------------------------------------------------------ an adapter whose constructor fails
class BrokenConstructor(PolynomialAdapter):
    """A third-party adapter whose constructor trips on something it did not check."""

    model_keys = PolynomialAdapter.model_keys

    @classmethod
    def from_config(cls, config, *, base_dir, scene_file=None):
        return {}["mesh"]  # a KeyError deep in the adapter's own code


def test_constructor_exception_names_the_adapter_and_the_scene(tmp_path, capsys, monkeypatch):
    M, K, G, H = random_system(N, seed=2)
    save_system(tmp_path / "s.npz", M, K, G, H)
    s = scene(tmp_path)
    use_solver(monkeypatch, lambda name: BrokenConstructor)
    o = run_cli(["run", s, "-q"], capsys)
    # exit 3 (an adapter failure, not a bug of stepnf: 1), the adapter's class and the scene named
    assert_reported(o, codes=(3,), mentions=[str(s), "'polynomial' adapter", "BrokenConstructor",
                                             "failed while building the model", "KeyError"])
    assert not (tmp_path / "out").exists()  # the folder this run made is removed again
