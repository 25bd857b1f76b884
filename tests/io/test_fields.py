"""Fields for ParaView (issue 13, item 4): mode shapes and second-order fields on the mesh, XDMF and VTU.

Small clamped caps (FEniCSx hex27, CalculiX hex20): the full-order evaluators
run on the adapters' K, M and G(phi, phi), :func:`stepnf.io.fields.write_mode_fields`
writes the files, and they are read back with meshio (XDMF) and VTK (VTU).
Values go through both files as float64 binary data, so what is read back
is what was written, bit for bit.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from stepnf.runtime.counters import Counters
from stepnf.errors import OutputError
from stepnf.nf.evaluators import FullOrderContext, dnf, md_full, nf_modal, retained_set, smd_full
from stepnf.io.fields import (OutputMesh, collect_fields, dof_placement, field_name, point_fields, write_fields,
                           write_mode_fields)
from stepnf.linalg.factorization import PseudoInverse
from stepnf.linalg.modal_analysis import modal_analysis
from stepnf.io.results import ModeResult
from helpers.fields import vtk_matches_xdmf
from helpers.required import requires

meshio = pytest.importorskip("meshio")

MAT = {"E": 1.04e11, "nu": 0.3, "rho": 4400.0}
CAP = {"a": 0.15, "R": 1.5, "h": 0.003, "n_core": 2, "n_ring": 1}
#: what one master mode gets: its shape and the vectors of DNF, MD and SMD (modal NF has none)
KINDS = ("phi", "dnf_a_bar", "dnf_w2_b_bar", "md_theta", "smd_theta")
#: masters: the axisymmetric (0,1) mode and the first of the degenerate (1,1) pair (MD borders its twin)
MASTERS = (0, 1)


def evaluate(K, M, Phi, omega, twins_of, labels, Gv_of, h_of):
    """ModeResults of MASTERS by NF (modal), DNF, MD and SMD (full order), and their G(phi, phi)."""
    ctx = FullOrderContext(K, M, PseudoInverse(K, M, np.zeros((K.shape[0], 0))), Counters())
    modes, Gvs = [], []
    for p in MASTERS:
        phi, w = Phi[:, p], float(omega[p])
        Gv, h = Gv_of(phi), h_of(phi)
        r_dnf, y = dnf(p, phi, w, Gv, h, ctx)
        tw = Phi[:, twins_of(p)] if twins_of(p) else None
        methods = {"nf": nf_modal(p, omega, Phi.T @ Gv, h, retained_set(p, None, len(omega))), "dnf": r_dnf,
                   "md": md_full(p, phi, w, Gv, h, ctx, tw, g=Phi.T @ Gv), "smd": smd_full(p, phi, w, Gv, h, ctx, y=y)}
        modes.append(ModeResult(index=p, label=labels[p], omega=w, rho=None, methods=methods))
        Gvs.append(Gv)
    return modes, Gvs


def backward_error(A: sp.spmatrix, x: np.ndarray, b: np.ndarray) -> float:
    """Normwise relative residual ``|A x - b| / (|A| |x| + |b|)`` (infinity norms) of a solve of ``A x = b``."""
    r = A @ x - b
    return float(np.abs(r).max() / (abs(A).sum(axis=1).max() * np.abs(x).max() + np.abs(b).max()))


def check_files(paths, stem: Path, ad, K, M, Phi, omega, modes, Gvs):
    """What every written run must satisfy (see the module docstring)."""
    assert [p.name for p in paths] == [f"{stem.name}_fields{s}" for s in (".h5", ".vtu", ".xdmf")]
    assert not (stem.parent / f"{stem.name}.h5").exists()  # the results file's name is not taken
    mesh = ad.output_mesh()
    back = meshio.read(paths[2])
    assert len(back.points) == mesh.n_points
    expected = {field_name(m.index, m.label, k) for m in modes for k in KINDS}
    assert set(back.point_data) == expected  # one field per master mode and per correction, none for NF
    pl = dof_placement(mesh, ad.dof_coordinates(), ad.dof_directions(), ad.n_dofs)
    assert pl.unmatched == 0 and np.all(pl.point >= 0)  # quadratic meshes: every dof on a point
    written = np.zeros((mesh.n_points, 3), dtype=bool)
    written[pl.point, pl.direction] = True
    assert (~written).any()  # the clamped rim's fixed dofs are not among the free ones ...
    for j, m in enumerate(modes):
        p, w2 = m.index, float(omega[m.index]) ** 2
        U = {k: back.point_data[field_name(p, m.label, k)] for k in KINDS}
        assert all(np.all(u[~written] == 0) for u in U.values())  # ... and are written as zeros
        dof = {k: u[pl.point, pl.direction] for k, u in U.items()}
        assert np.array_equal(dof["phi"], Phi[:, p])  # a copy, exactly
        # mass norm: phi is M-normalised by the eigen-solver; what is left is the round-off of the n-term
        # sum phi^T M phi (n ~ 400-600: a few 1e-16 relative; measured 2.2e-16); 1e-12 leaves a margin of 1e3+
        assert float(dof["phi"] @ (M @ dof["phi"])) == pytest.approx(1.0, abs=1e-12)
        # a_bar (with w2_b_bar) solves its two defining systems (docs/design.md, Eq. 9-10, clamped: no rigid modes):
        #   K (a_bar + w^2 b_bar) = -Gv,  (K - 4 w^2 M)(a_bar - w^2 b_bar) = -Gv.
        # A backward-stable direct solve (LU with partial pivoting: dense LAPACK at these sizes, else MUMPS or
        # SuperLU) leaves a normwise backward error of a few eps times the pivot growth: measured 1.1e-16 ..
        # 1.9e-16 on the FEniCSx cap; 1e-12 leaves 1e3+ for other BLAS and orderings, while a field from a
        # wrong equation or a wrong dof placement has an O(1) residual.
        a, b = dof["dnf_a_bar"], dof["dnf_w2_b_bar"]
        Gv = Gvs[j]
        assert backward_error(K, a + b, -Gv) < 1e-12
        assert backward_error((K - 4 * w2 * M).tocsr(), a - b, -Gv) < 1e-12
        assert backward_error(K, dof["smd_theta"], -2 * Gv) < 1e-12  # SMD: theta = -2 K^+ Gv
        # MD: (K - w^2 M) theta = -2 Gv on the complement of phi (and its twin): M-orthogonal to them. The
        # bordered solve meets its constraint rows to eps times the condition of the bordered matrix
        # (measured 2.0e-12 .. 2.2e-12 of |theta|_M); 1e-10 leaves a factor 50 (a free theta: ~1).
        th = dof["md_theta"]
        assert abs(float(Phi[:, p] @ (M @ th))) <= 1e-10 * np.sqrt(float(th @ (M @ th)))
        assert np.array_equal(dof["dnf_a_bar"], m.methods["dnf"].fields["a_bar"])
    vtk_matches_xdmf(paths[1], back)


# ------------------------------------------------------------------ FEniCSx
@pytest.mark.fenicsx
def test_fenicsx_cap_fields(tmp_path):
    pytest.importorskip("dolfinx")
    from stepnf_fenicsx import FenicsxAdapter

    g = dict(CAP)
    ad = FenicsxAdapter.cap(g.pop("a"), g.pop("R"), g.pop("h"), **MAT, **g, boundary=[{"set": "edge"}])
    K, M = ad.stiffness_matrix(), ad.mass_matrix()
    basis = modal_analysis(K, M, 6)
    assert basis.rigid.shape[1] == 0
    labels = ad.mode_labels(basis.phi)
    modes, Gvs = evaluate(K, M, basis.phi, basis.omega, basis.twins, labels,
                          lambda v: ad.quadratic_force(v, v), lambda v: float(v @ ad.cubic_force(v, v, v)))
    paths = write_mode_fields(tmp_path / "run.h5", ad.output_mesh(), modes, basis.phi[:, list(MASTERS)],
                              ad.dof_coordinates(), ad.dof_directions(), who="fenicsx")
    assert field_name(0, labels[0], "phi") == "mode_0_(0,1)_phi"
    check_files(paths, tmp_path / "run", ad, K, M, basis.phi, basis.omega, modes, Gvs)


# ------------------------------------------------------------------ CalculiX
@pytest.mark.calculix
@requires("ccx")
def test_calculix_cap_fields(tmp_path):
    ccx = pytest.importorskip("stepnf_calculix")
    cfg = {"element": "hex20", "geometry": {"shape": "spherical_cap", **CAP},
           "material": MAT, "keep": "never", "threads": 1, "boundary": [{"set": "edge"}]}
    ad = ccx.CalculixAdapter.from_config(cfg, base_dir=tmp_path, scene_file=tmp_path / "s.toml")
    K, M = ad.stiffness_matrix(), ad.mass_matrix()
    basis = modal_analysis(K, M, 6)
    assert basis.rigid.shape[1] == 0
    q = 0.003 / np.abs(basis.phi[:, list(MASTERS)]).max()  # STEP amplitude: a thickness at the largest dof
    # G(phi, phi) by STEP from two printed-force fields per master (its digits do not matter here: the
    # checks below are of the solves against the Gv they were given)
    F = ad.internal_forces(np.concatenate([[q * basis.phi[:, p], -q * basis.phi[:, p]] for p in MASTERS]))
    G = {p: (F[2 * i] + F[2 * i + 1]) / (2 * q * q) for i, p in enumerate(MASTERS)}
    H = {p: float(basis.phi[:, p] @ ((F[2 * i] - F[2 * i + 1]) / (2 * q) - K @ basis.phi[:, p])) / (q * q)
         for i, p in enumerate(MASTERS)}

    def which(v):
        return next(p for p in MASTERS if v is basis.phi[:, p] or np.array_equal(v, basis.phi[:, p]))

    modes, Gvs = evaluate(K, M, basis.phi, basis.omega, basis.twins, ad.mode_labels(basis.phi),
                          lambda v: G[which(v)], lambda v: H[which(v)])
    paths = write_mode_fields(tmp_path / "run.h5", ad.output_mesh(), modes, basis.phi[:, list(MASTERS)],
                              ad.dof_coordinates(), ad.dof_directions(), who="calculix")
    check_files(paths, tmp_path / "run", ad, K, M, basis.phi, basis.omega, modes, Gvs)


# ------------------------------------------------------------------ without a solver
def _tiny():
    """Two hexahedra (12 points), 36 dofs, and two fields."""
    x, y, z = np.meshgrid([0.0, 1.0, 2.0], [0.0, 1.0], [0.0, 1.0], indexing="ij")
    pts = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    idx = np.arange(12).reshape(3, 2, 2)
    cells = np.array([[idx[i, 0, 0], idx[i + 1, 0, 0], idx[i + 1, 1, 0], idx[i, 1, 0],
                       idx[i, 0, 1], idx[i + 1, 0, 1], idx[i + 1, 1, 1], idx[i, 1, 1]] for i in range(2)])
    return OutputMesh(pts, [("hexahedron", cells)])


def test_placement_zeros_fixed_and_rotation_dofs():
    mesh = _tiny()
    rng = np.random.default_rng(0)
    order = rng.permutation(36)[:30]  # 6 dofs fixed (removed), the others in a scrambled order
    X = np.repeat(mesh.points, 3, axis=0)[order] + 1e-12  # coordinates through round-off
    D = np.tile(np.arange(3), 12)[order]
    D[0] = 4  # a rotation dof: not a displacement, not written
    pl = dof_placement(mesh, X, D, 30)
    v = rng.standard_normal(30)
    U = point_fields({"f": v}, pl, 12)["f"]
    full = np.zeros(36)
    full[order[1:]] = v[1:]
    assert np.array_equal(U.ravel(), full)


def test_no_dof_on_the_mesh_and_bad_lengths_are_refused():
    from stepnf.errors import AdapterError

    mesh = _tiny()
    with pytest.raises(AdapterError, match="none of its dofs"):
        dof_placement(mesh, np.full((3, 3), 10.0), np.arange(3), 3, "toy")
    with pytest.raises(AdapterError, match=r"toy: dof_coordinates\(\) has shape"):
        dof_placement(mesh, np.zeros((3, 3)), np.arange(2), 3, "toy")
    with pytest.raises(AdapterError, match="needs dof_coordinates"):
        dof_placement(mesh, None, None, 3, "toy")


def test_names_are_safe_and_methods_keep_their_fields_out_of_json():
    assert field_name(3, (2, 0), "dnf_a_bar") == "mode_3_(2,0)_dnf_a_bar"
    assert field_name(3, None, "phi") == "mode_3_phi"
    assert field_name(3, 'a b"<&>', "phi") == "mode_3_a_b_____phi"
    K = sp.diags([1.0, 5.0, 11.0]).tocsr()  # no mode at twice w = 1
    M = sp.identity(3, format="csr")
    ctx = FullOrderContext(K, M, PseudoInverse(K, M, np.zeros((3, 0))), Counters())
    Gv = np.array([0.0, 0.5, 0.25])
    r, y = dnf(0, np.array([1.0, 0, 0]), 1.0, Gv, 0.1, ctx)
    assert set(r.fields) == {"a_bar", "w2_b_bar"} and "a_bar" not in r.to_dict()
    json.dumps(r.to_dict(), allow_nan=False)  # nothing but plain numbers in JSON
    ctx.keep_fields = False
    assert dnf(0, np.array([1.0, 0, 0]), 1.0, Gv, 0.1, ctx)[0].fields == {}
    assert smd_full(0, np.array([1.0, 0, 0]), 1.0, Gv, 0.1, ctx).fields == {}
    mr = ModeResult(index=0, label=None, omega=1.0, rho=None, methods={"dnf": r})
    assert set(collect_fields([mr], np.eye(3)[:, :1])) == {"mode_0_phi", "mode_0_dnf_a_bar", "mode_0_dnf_w2_b_bar"}


def test_dnf_fields_give_the_second_order_motion():
    """The stated convention, against a time integration: on the backbone of a 2-dof system
    (``x'' + K x + G(x, x) = 0``, ``K = diag(1, 2.5^2)``, potential ``x1^2 x2``: ``G(x, x) = (2 x1 x2, x1^2)``)
    started at ``x(0) = a phi + a^2 a_bar``, ``x'(0) = 0``, the slave coordinate follows
    ``a^2 [cos^2(w t) a_bar + sin^2(w t) w2_b_bar]`` over a period, to a relative error that falls like a^2
    (the next terms of the normal form are O(a^4) in the slave); a_bar and w2_b_bar swapped is off by O(1)."""
    from scipy.integrate import solve_ivp

    K = sp.diags([1.0, 2.5**2]).tocsr()
    M = sp.identity(2, format="csr")
    ctx = FullOrderContext(K, M, PseudoInverse(K, M, np.zeros((2, 0))), Counters())
    phi = np.array([1.0, 0.0])
    r, _ = dnf(0, phi, 1.0, np.array([0.0, 1.0]), 0.0, ctx)
    ab, wb = r.fields["a_bar"][1], r.fields["w2_b_bar"][1]

    def rhs(t, s):
        x = s[:2]
        return np.concatenate([s[2:], -(K @ x + np.array([2 * x[0] * x[1], x[0] ** 2]))])

    errors, wrong = [], []
    amplitudes = np.array([1e-2, 5e-3, 2.5e-3])
    for a in amplitudes:
        w = 1.0 + r.T * a * a  # the backbone frequency, so that the phase does not drift over the period
        t = np.linspace(0.0, 2 * np.pi / w, 200)
        # DOP853 at rtol 1e-12: integration error ~1e-12 of a, far below the a^4 ~ 1e-10 .. 4e-11 measured
        sol = solve_ivp(rhs, (0.0, t[-1]), [a, a * a * ab, 0.0, 0.0], t_eval=t, rtol=1e-12, atol=1e-16,
                        method="DOP853")
        c2, s2 = np.cos(w * t) ** 2, np.sin(w * t) ** 2
        pred = a * a * (c2 * ab + s2 * wb)
        errors.append(np.abs(sol.y[1] - pred).max() / np.abs(pred).max())
        wrong.append(np.abs(sol.y[1] - a * a * (c2 * wb + s2 * ab)).max() / np.abs(pred).max())
    rate = np.polyfit(np.log(amplitudes), np.log(errors), 1)[0]
    assert 1.8 < rate < 2.2  # measured 2.00 (9.5e-5, 2.4e-5, 5.9e-6)
    assert errors[0] < 1e-3 and min(wrong) > 1.0  # measured 1.47 for the swapped fields


def test_write_failure_names_the_file_and_keeps_the_old_files(tmp_path):
    mesh = _tiny()
    f = {"mode_0_phi": np.ones((12, 3))}
    paths = write_fields(tmp_path / "run_fields", mesh, f)
    before = [p.read_bytes() for p in paths]
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OutputError, match=r"cannot write the field file .*file/run_fields"):
        write_fields(blocker / "run_fields", mesh, f)  # a folder that is a file
    bad = OutputMesh(mesh.points, [("no_such_cell", mesh.cells[0][1])])
    with pytest.raises(OutputError, match=r"run_fields.xdmf: meshio failed"):
        write_fields(tmp_path / "run_fields", bad, f)
    assert [p.read_bytes() for p in paths] == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "run_fields.h5", "run_fields.vtu",
                                                          "run_fields.xdmf"]  # no temporary left


def test_scene_key(tmp_path):
    from stepnf.errors import SceneError
    from stepnf.scene.parse import load_scene

    text = '[model]\nsolver = "polynomial"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\n'
    (tmp_path / "a.toml").write_text(text + "[output]\n")
    (tmp_path / "b.toml").write_text(text + "[output]\nfields = false\n")
    (tmp_path / "c.toml").write_text(text + '[output]\nfields = "no"\n')
    np.savez(tmp_path / "s.npz", K=np.eye(2), M=np.eye(2))
    assert load_scene(tmp_path / "a.toml").fields is True
    assert load_scene(tmp_path / "b.toml").fields is False
    with pytest.raises(SceneError, match=r"output\.fields"):
        load_scene(tmp_path / "c.toml")


def test_mesh_that_misses_the_dofs_is_an_output_error(tmp_path):
    mesh = _tiny()
    mr = ModeResult(index=0, label=None, omega=1.0, rho=None)
    with pytest.raises(OutputError, match=r"run_fields\.xdmf: toy: none of its dofs lies on a point"):
        write_mode_fields(tmp_path / "run.h5", mesh, [mr], np.ones((3, 1)), np.full((3, 3), 9.0), np.arange(3),
                          who="toy")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ through a scene
SCENE = """\
[model]
solver = "fenicsx"
[model.geometry]
shape = "spherical_cap"
a = 0.15
R = 1.5
h = 0.003
n_core = 2
n_ring = 1
[model.material]
E = 1.04e11
nu = 0.3
rho = 4400.0
[[model.boundary]]
set = "edge"
[analysis]
master_modes = [0, 1]
methods = ["nf", "dnf", "md", "smd"]
[output]
dir = "out"
{fields}
"""


@pytest.mark.fenicsx
def test_scene_writes_fields_beside_the_results(tmp_path):
    """The default writes NAME_fields.{h5,vtu,xdmf} beside NAME.h5; ``[output] fields = false`` writes none."""
    pytest.importorskip("dolfinx")
    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import load_scene

    (tmp_path / "on.toml").write_text(SCENE.format(fields=""))
    (tmp_path / "off.toml").write_text(SCENE.format(fields="fields = false"))
    run_scene(load_scene(tmp_path / "off.toml"))
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["off.h5"]
    res = run_scene(load_scene(tmp_path / "on.toml"))
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == ["off.h5", "on.h5", "on_fields.h5", "on_fields.vtu", "on_fields.xdmf"]
    back = meshio.read(tmp_path / "out" / "on_fields.xdmf")
    assert set(back.point_data) == {field_name(m.index, m.label, k) for m in res.modes for k in KINDS}
    assert sorted(Path(p).name for p in res.extra_files) == ["on_fields.h5", "on_fields.vtu", "on_fields.xdmf"]
    # written, then dropped from the result (the files hold them; a sweep's results stay small)
    assert all(not r.fields for m in res.modes for r in m.methods.values())


# ------------------------------------------------------------------ through stepnf run, adapter faults
def _chain_scene(tmp_path, monkeypatch, output_mesh):
    """A 4-node chain of ux, uy, uz dofs (polynomial system) whose adapter's output_mesh is ``output_mesh``."""
    from stepnf_polynomial import PolynomialAdapter, save_system
    from helpers.systems import random_system, use_solver

    n_nodes = 4
    M, K, G, H = random_system(3 * n_nodes, seed=7)
    X = np.repeat(np.column_stack([np.arange(float(n_nodes)), np.zeros(n_nodes), np.zeros(n_nodes)]), 3, axis=0)
    save_system(tmp_path / "s.npz", M, K, G, H, coordinates=X, directions=np.tile([0, 1, 2], n_nodes))

    class Meshed(PolynomialAdapter):
        pass

    Meshed.output_mesh = output_mesh
    use_solver(monkeypatch, lambda name: Meshed)
    p = tmp_path / "s.toml"
    p.write_text('[model]\nsolver = "polynomial"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0]\n'
                 'methods = ["dnf"]\n[output]\ndir = "out"\nplot = false\n')
    return p


LINE = OutputMesh(np.column_stack([np.arange(4.0), np.zeros(4), np.zeros(4)]),
                  [("line", np.array([[0, 1], [1, 2], [2, 3]]))])


def test_run_writes_fields_for_any_adapter_with_an_output_mesh(tmp_path, monkeypatch, capsys):
    from stepnf.cli.main import main

    assert main(["run", str(_chain_scene(tmp_path, monkeypatch, lambda self: LINE)), "-q"]) == 0
    out = capsys.readouterr().out
    assert "fields: " in out and (tmp_path / "out" / "s_fields.xdmf").exists()
    back = meshio.read(tmp_path / "out" / "s_fields.xdmf")
    assert set(back.point_data) == {"mode_0_phi", "mode_0_dnf_a_bar", "mode_0_dnf_w2_b_bar"}


def test_an_output_mesh_that_raises_costs_the_fields_only(tmp_path, monkeypatch, capsys):
    """The adapter's bug is one warning naming it; T is computed, printed and stored (exit 0)."""
    from stepnf.cli.main import main

    def broken(self):
        raise RuntimeError("no mesh today")

    from stepnf.errors import OutputWarning

    scene = _chain_scene(tmp_path, monkeypatch, broken)
    with pytest.warns(OutputWarning, match=r"no field files: .*Meshed.*RuntimeError: no mesh today"):
        assert main(["run", str(scene), "-q"]) == 0  # on stderr as "stepnf: warning: ..."
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err and "dnf" in cap.out
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["s.h5"]


def test_an_output_mesh_that_does_not_fit_the_dofs_is_exit_3_and_keeps_the_results(tmp_path, monkeypatch,
                                                                                   capsys):
    from stepnf.cli.main import main

    far = OutputMesh(LINE.points + 100.0, LINE.cells)
    assert main(["run", str(_chain_scene(tmp_path, monkeypatch, lambda self: far)), "-q"]) == 3
    cap = capsys.readouterr()
    assert "s_fields.xdmf" in cap.err and "Traceback" not in cap.err
    assert "dnf" in cap.out  # the computed table is still shown
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["s.h5"]
