"""Shell elements in a user's CalculiX deck (issue 32, item 4): refused, for a reason measured here with ccx.

CalculiX expands a shell into a 3D solid and ties each shell node's six dofs to the expanded nodes. The
probe below prescribes all six dofs at every shell node of a flat plate (``*BOUNDARY`` 1-6, ``*STATIC``
NLGEOM, as stepnf's force steps do) and finds the three facts :data:`stepnf_calculix.userdeck.SHELL_REASON`
states: ``*NODE PRINT RF`` prints three components per node (forces, no moments at the prescribed
rotations), ``*FREQUENCY, SOLVER=MATRIXSTORAGE`` exports K over the expanded nodes' translations (not 6 per
shell node), and a rigid rotation of 0.5 degree about an in-plane axis does not converge (S4 and S8R here; the
same rotation about the normal gives zero force, so the probe's rigid motion is right). If a later ccx changes any of
these, the probe fails and the refusal must be measured again.
"""
from __future__ import annotations

import os
import re
import subprocess

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from helpers.hostile import assert_reported, run_cli
from helpers.required import requires

from stepnf.errors import SceneError

pytestmark = [pytest.mark.calculix]
ccx_mod = pytest.importorskip("stepnf_calculix")
from stepnf_calculix.userdeck import read_deck  # noqa: E402

L, H, E, NU, RHO = 0.1, 0.002, 2.1e11, 0.3, 7800.0


def plate(element: str) -> tuple[np.ndarray, list[tuple[int, ...]], list[int]]:
    """A flat L x L plate in z = 0 on a 5 x 5 grid of nodes: 4 x 4 S4, 2 x 2 S8/S8R, 8 S3 or S6 cells (1-based
    node ids), and the ids the cells use."""
    xs = np.linspace(0.0, L, 5)
    X = np.array([(x, y, 0.0) for y in xs for x in xs])
    n = lambda i, j: 5 * j + i + 1  # noqa: E731
    if element == "S4":
        cells = [(n(i, j), n(i + 1, j), n(i + 1, j + 1), n(i, j + 1)) for j in range(4) for i in range(4)]
    else:
        cells = []
        for j in (0, 2):
            for i in (0, 2):
                c = [n(i, j), n(i + 2, j), n(i + 2, j + 2), n(i, j + 2)]
                mid = [n(i + 1, j), n(i + 2, j + 1), n(i + 1, j + 2), n(i, j + 1)]
                centre = n(i + 1, j + 1)  # the diagonal's midpoint
                cells += {"S8": [(*c, *mid)], "S8R": [(*c, *mid)], "S3": [(c[0], c[1], c[2]), (c[0], c[2], c[3])],
                          "S6": [(c[0], c[1], c[2], mid[0], mid[1], centre),
                                 (c[0], c[2], c[3], centre, mid[2], mid[3])]}[element]
    return X, cells, sorted({k for c in cells for k in c})


def deck(element: str, steps: str = "") -> str:
    X, cells, used = plate(element)
    lines = ["*NODE, NSET=NALL"] + [f"{k}, {X[k - 1, 0]:.13e}, {X[k - 1, 1]:.13e}, 0." for k in used]
    lines += [f"*ELEMENT, TYPE={element}, ELSET=EALL"] + [f"{e + 1}, " + ", ".join(map(str, c))
                                                          for e, c in enumerate(cells)]
    lines += ["*MATERIAL, NAME=STEEL", "*ELASTIC", f"{E}, {NU}", "*DENSITY", f"{RHO}",
              "*SHELL SECTION, ELSET=EALL, MATERIAL=STEEL", f"{H}"]
    return "\n".join(lines) + "\n" + steps


# ------------------------------------------------------------------------------- the refusal
@pytest.mark.parametrize("element", ["S3", "S4", "S6", "S8", "S8R"])
def test_a_shell_deck_is_refused_naming_the_line_the_element_and_the_reason(tmp_path, element):
    (tmp_path / "panel.inp").write_text(deck(element))
    head = deck(element).splitlines().index(f"*ELEMENT, TYPE={element}, ELSET=EALL") + 1
    with pytest.raises(SceneError) as ei:
        read_deck(tmp_path / "panel.inp")
    msg = str(ei.value)
    assert "\n" not in msg and "panel.inp" in msg and f"line {head}" in msg and repr(element) in msg, msg
    assert "no moments" in msg and "does not converge" in msg and "kratos" in msg, msg


def test_a_shell_section_before_the_elements_gives_the_same_reason(tmp_path):
    text = deck("S4")
    text = text.replace("*SHELL SECTION, ELSET=EALL, MATERIAL=STEEL\n0.002\n", "")
    text = text.replace("*ELEMENT", "*SHELL SECTION, ELSET=EALL, MATERIAL=STEEL\n0.002\n*ELEMENT", 1)
    (tmp_path / "panel.inp").write_text(text)
    with pytest.raises(SceneError, match=r"panel\.inp: line \d+: \*SHELL SECTION: a shell section: .*no moments"):
        read_deck(tmp_path / "panel.inp")


def test_a_shell_deck_through_the_cli_exits_2(tmp_path, capsys):
    (tmp_path / "panel.inp").write_text(deck("S8R"))
    (tmp_path / "s.toml").write_text('[model]\nsolver = "calculix"\ndeck = "panel.inp"\n[analysis]\n'
                                     'master_modes = [0]\nmethods = ["dnf"]\n[output]\ndir = "out"\n')
    o = run_cli(["run", tmp_path / "s.toml", "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=["panel.inp", "'S8R'", "no moments"])


# ------------------------------------------------------------------------------- the measurement
def _ccx(folder, name: str, text: str) -> tuple[str, str]:
    (folder / f"{name}.inp").write_text(text)
    r = subprocess.run(["ccx", name], cwd=folder, capture_output=True, text=True, timeout=120,
                       env={**os.environ, "OMP_NUM_THREADS": "1"})
    dat = folder / f"{name}.dat"
    return r.stdout, dat.read_text() if dat.is_file() else ""


def _prescribed(U: np.ndarray, used: list[int]) -> str:
    rows = [f"{k}, {d + 1}, {d + 1}, {U[i, d]:.13e}" for i, k in enumerate(used) for d in range(6)]
    return ("*STEP, NLGEOM\n*STATIC, DIRECT\n1., 1.\n*BOUNDARY\n" + "\n".join(rows)
            + "\n*NODE PRINT, NSET=NALL\nRF\n*END STEP\n")


def _rigid(axis: str, degrees: float, X: np.ndarray) -> np.ndarray:
    R = Rotation.from_euler(axis, degrees, degrees=True)
    c = X.mean(axis=0)
    U = np.zeros((len(X), 6))
    U[:, :3] = R.apply(X - c) + c - X
    U[:, 3:] = R.as_rotvec()  # ccx's rotation dofs: the rotation vector (right for the rotation about z below)
    return U


@requires("ccx")
def test_ccx_shell_nodes_give_no_moments_no_rotational_matrix_and_fail_a_rigid_rotation(tmp_path):
    X_all, _, used = plate("S4")
    X = X_all[np.array(used) - 1]
    w = H * np.sin(np.pi * X[:, 0] / L) * np.sin(np.pi * X[:, 1] / L)  # a bending field of one thickness
    U = np.zeros((len(X), 6))
    U[:, 2] = w
    U[:, 3] = H * np.pi / L * np.sin(np.pi * X[:, 0] / L) * np.cos(np.pi * X[:, 1] / L)  # rx = dw/dy
    U[:, 4] = -H * np.pi / L * np.cos(np.pi * X[:, 0] / L) * np.sin(np.pi * X[:, 1] / L)  # ry = -dw/dx
    out, dat = _ccx(tmp_path, "bend", deck("S4", _prescribed(U, used)))
    assert "ERROR" not in out, out[-800:]
    assert "forces (fx,fy,fz) for set NALL" in dat and "moment" not in dat.lower(), dat[:400]
    rows = re.findall(r"^[ \t]*\d+((?:[ \t]+\S+)+)[ \t]*$", dat.split("forces (fx,fy,fz)")[1], re.M)
    assert len(rows) == len(used) and {len(r.split()) for r in rows} == {3}  # 3 numbers a node, not 6
    assert max(abs(float(v)) for r in rows for v in r.split()) > 1e3  # the field does load the plate (N)

    out, _ = _ccx(tmp_path, "mat", deck("S4", "*STEP\n*FREQUENCY, SOLVER=MATRIXSTORAGE\n*END STEP\n"))
    dofs = np.loadtxt(tmp_path / "mat.dof")
    directions = np.round(10 * (dofs % 1)).astype(int)
    assert set(directions) == {1, 2, 3} and len(dofs) != 6 * len(used)  # translations of the expanded nodes

    out, dat = _ccx(tmp_path, "spin", deck("S4", _prescribed(_rigid("z", 30.0, X), used)))
    f = np.array([[float(v) for v in r.split()] for r in
                  re.findall(r"^[ \t]*\d+((?:[ \t]+\S+){3})[ \t]*$", dat.split("forces (fx,fy,fz)")[1], re.M)])
    assert "ERROR" not in out and np.abs(f).max() < 1e-5  # N; ~5e-7 measured (the bending field: ~3e4)

    for element in ("S4", "S8R"):  # measured: S3, S4, S8 fail from 0.1 degree, S8R from 0.5 degree
        _, _, on = plate(element)
        tilt = _rigid("x", 0.5, X_all[np.array(on) - 1])
        out, _ = _ccx(tmp_path, f"tilt{element}", deck(element, _prescribed(tilt, on)))
        assert "*ERROR" in out and "diverge" in out, out[-800:]
