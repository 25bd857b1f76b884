"""The documented FE examples, re-run: Kirchhoff frequencies, the von Karman plate and stored numbers.

References are independent of the FE model: the free circular plate's
frequencies (Kirchhoff theory, nu = 0.3) and Gamma of the von Karman plate
model (:mod:`stepnf.models.vonkarman`, Bessel modes and Airy functions,
converged to 1e-7). The 3D solid includes transverse shear, rotary and
in-plane inertia that the plate theory leaves out, so agreement is expected
to about 1% for the first modes and a few % for higher ones (issue 3: 2%).
"""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from stepnf.nf.evaluators import nf_modal
from stepnf.io.fields import field_name
from stepnf.models.vonkarman import VonKarmanShell
from stepnf.pipeline.run import run_scene
from stepnf.scene.parse import load_scene
from stepnf.report.table import format_table
from helpers.fields import vtk_matches_xdmf
from helpers.paths import EXAMPLES

pytestmark = [pytest.mark.fenicsx, pytest.mark.slow]
KIRCHHOFF = {(2, 0): 5.358, (0, 1): 9.003, (3, 0): 12.439}


def vonkarman_gamma(kappa: float) -> dict:
    vk = VonKarmanShell(kappa=kappa, nu=0.3)
    om, labels, wmax = vk.omegas(), vk.labels(), vk.mode_maxima()
    out = {}
    for lab in [(2, 0), (3, 0), (4, 0), (0, 1), (0, 2), (2, 1)]:
        p = labels.index(lab)
        r = nf_modal(p, om, vk.quadratic_coefficients(p), vk.cubic_coefficient(p), np.arange(len(om)))
        out[lab] = r.T / wmax[p] ** 2
    return out


def run_example(name: str, tmp_path: Path):
    scene = load_scene(EXAMPLES / name)
    scene.output_dir = tmp_path
    res = run_scene(scene)
    return {tuple(m.label): m for m in res.modes}, res


def test_plate_example(tmp_path):
    modes, res = run_example("plate.toml", tmp_path)
    for lab, wbar in KIRCHHOFF.items():  # issue 3: within 0.5 % on the default mesh
        assert modes[lab].omega_bar == pytest.approx(wbar, rel=5e-3)
    vk = vonkarman_gamma(0.0)
    # measured: (2,0) 0.15%, (3,0) 0.5%, (4,0) 0.9%, (0,1) 0.35%; (0,2) 2.1%, (2,1) 2.2% (3D effects grow
    # with the mode's wavenumber, and (2,1) moves away from the plate value under refinement)
    for lab in [(2, 0), (3, 0), (4, 0), (0, 1)]:
        assert modes[lab].methods["dnf"].gamma == pytest.approx(vk[lab], rel=0.02)
    for lab in [(0, 2), (2, 1)]:
        assert modes[lab].methods["dnf"].gamma == pytest.approx(vk[lab], rel=0.03)
    # the flat plate: slow/fast holds for every mode (in-plane modes are far above): MD = SMD = DNF
    for m in modes.values():
        for meth in ("md", "smd"):
            assert m.methods[meth].gamma == pytest.approx(m.methods["dnf"].gamma, rel=2e-3)
        # modal NF over 20 transverse modes misses the in-plane part of G entirely: flagged
        assert any(f["kind"] == "modal_truncation" for f in m.methods["nf"].flags)
    assert Path(res.hdf5_path).exists()
    # issue 13: the printed table shows those NF numbers as n/a with the reason; JSON keeps them
    table = format_table(res)
    nf_rows = [line.split() for line in table.splitlines() if " nf " in f" {line} " and "n/a" in line]
    assert len(nf_rows) == len(modes), table
    assert table.count("n/a [") == len(modes) and "G(phi_p, phi_p)" in table
    assert all(isinstance(m["methods"]["nf"]["T"], float) for m in json.loads(res.to_json())["modes"])


STORED_K25 = {  # DNF Gamma of examples/shell_kappa25.toml (38k dofs), this code, for regression
    (2, 0): 0.014013, (3, 0): 0.176038, (4, 0): 0.154218, (0, 1): -0.231951, (0, 2): -0.059913, (2, 1): 0.077235}


def test_kappa25_example(tmp_path):
    modes, res = run_example("shell_kappa25.toml", tmp_path)
    assert res.kappa == pytest.approx(25.0)
    for lab, g in STORED_K25.items():
        # (3,0) is an exactly degenerate pair whose basis the eigen-solver picks; the 4-fold mesh makes T
        # depend on it at the 1e-3 level
        assert modes[lab].methods["dnf"].gamma == pytest.approx(g, rel=5e-3)
    vk = vonkarman_gamma(25.0)
    for lab in [(3, 0), (4, 0), (0, 1)]:  # measured 0.4%, 0.3%, 0.3%
        assert modes[lab].methods["dnf"].gamma == pytest.approx(vk[lab], rel=0.02)
    # the paper's point: without slow/fast separation MD and SMD predict the wrong type of nonlinearity
    wrong = {(3, 0): ("md", "smd"), (0, 2): ("md",), (2, 1): ("md", "smd")}
    for lab, meths in wrong.items():
        for meth in meths:
            assert math.copysign(1, modes[lab].methods["dnf"].T) != math.copysign(1, modes[lab].methods[meth].T)
    # ... and agree with DNF where it holds, or for (0,1) which one mode describes well (paper 3.2)
    assert modes[(0, 1)].methods["md"].gamma == pytest.approx(modes[(0, 1)].methods["dnf"].gamma, rel=0.05)
    # (4,0) lies near a 1:2 resonance with (0,2) (w ratio 1.90): flagged, naming it
    flags = modes[(4, 0)].methods["dnf"].flags
    assert any(f["kind"] == "internal_resonance_1_2" and f["label"] == (0, 2) for f in flags)
    assert res.counts["factorizations"] <= 4 and res.counts["force_evaluations"] == 24
    # issue 13: the ParaView files beside the results: one field per master mode and per correction,
    # read back by meshio (XDMF) and by VTK's own reader (VTU, where Debian's python3-vtk9 is installed)
    meshio = pytest.importorskip("meshio")
    xdmf = Path(res.hdf5_path).with_name("shell_kappa25_fields.xdmf")
    back = meshio.read(xdmf)
    kinds = ("phi", "dnf_a_bar", "dnf_w2_b_bar", "md_theta", "smd_theta")
    assert set(back.point_data) == {field_name(m.index, m.label, k) for m in res.modes for k in kinds}
    assert all(u.shape == (len(back.points), 3) for u in back.point_data.values())
    vtk_matches_xdmf(xdmf.with_suffix(".vtu"), back)
