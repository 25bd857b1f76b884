"""The DPIM backbone of a model in modal coordinates (the von Karman shell): :mod:`stepnf.pipeline.modal_forces`
and the backbone of :mod:`stepnf.pipeline.modal_coordinates`.

References: the model's own g^s_pp and h^p_ppp (computed by its own routine, ``_couple``), its modal
normal form over the same modes (order 3 of the DPIM is the NF's T), and periodic orbits of a 2-mode
truncation by shooting (:class:`stepnf.verify.periodic.Shooting`, DOP853 at rtol 1e-12).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from stepnf.errors import SceneError
from stepnf.plugin.modal_model import ModalModel
from stepnf.models.vonkarman import VonKarmanShell
from stepnf.verify.periodic import Shooting
from stepnf.runtime.progress import Progress
from stepnf.io.results import read_hdf5, write_hdf5
from stepnf.scene.parse import Tolerances, parse_scene
from stepnf.pipeline.apply_method import modal_method
from stepnf.pipeline.modal_coordinates import modal_dpim, run_modal_model
from stepnf.pipeline.modal_forces import ModalSystem, VonKarmanForces, modal_system

SIX = [(2, 0), (3, 0), (4, 0), (0, 1), (0, 2), (2, 1)]


@pytest.fixture(scope="module")
def shell() -> VonKarmanShell:
    return VonKarmanShell(kappa=25.0)


@pytest.mark.parametrize("label", SIX, ids=str)
def test_forces_reproduce_the_model_coefficients(shell, label):
    """G(phi_p, phi_p) and h^p_ppp of the modal force equal the model's g^s_pp (every s) and h^p_ppp.

    STEP at q = 0.1 is exact for the cubic force; the round-off is that of f(+-q e_p) (~1e-16 x omega^2 q,
    omega^2 up to ~1e4 on the modes kept) divided by q^2 (G) and q^3 (H): <= ~1e-10 relative to g and h
    (measured <= 6e-15 for G and 2e-12 for H at q = 0.01). Modes outside the master's invariant subspace
    have g^s_pp = 0 exactly (selection rules), so the subspace loses nothing.
    """
    p = shell.index(*label)
    sysm = modal_system(shell, p)
    e = np.zeros(len(sysm.index))
    e[sysm.local] = 1.0
    q = 0.1
    fp, fm = sysm.forces(q * e)[0], sysm.forces(-q * e)[0]
    G = (fp + fm) / (2 * q * q)
    H = ((fp - fm) / 2 - q * sysm.omega ** 2 * e) / q ** 3
    g = shell.quadratic_coefficients(p)
    assert np.abs(G - g[sysm.index]).max() <= 1e-10 * max(np.abs(g).max(), 1.0)
    assert np.abs(np.delete(g, sysm.index)).max(initial=0.0) == 0.0
    assert H[sysm.local] == pytest.approx(shell.cubic_coefficient(p), rel=1e-10)


@pytest.mark.parametrize("label", [(2, 1), (0, 2), (4, 0)], ids=str)
def test_tangent_is_the_derivative_of_the_forces(shell, label):
    """``VonKarmanForces.tangent(x)`` against central differences of the forces, and one batch against its rows.

    A field of modal size ~0.3 (W_max/h ~ 0.4 on these modes, the backbones' range). Central differences with
    step h = 1e-4 err by ``h^2 |D^3 f| / 6`` (the force is a cubic polynomial: a constant third derivative of
    the order of the cubic coefficients, ~1e3..1e4 here, as ``|Df| ~ omega^2``): ~2e-9 relative, plus the
    round-off ``1e-16 |f| / h ~ 1e-12``; 1e-7 bounds both (measured 7e-11 .. 2e-10 at h = 1e-5). The tangent is a
    Hessian: symmetric to the products' round-off (~1e-16; 1e-13). A batch equals its rows evaluated one by one
    to round-off (1e-13 relative).
    """
    vf = VonKarmanForces(shell, shell.index(*label))
    n = len(vf.index)
    x = 0.3 * np.random.default_rng(7).standard_normal(n) / np.sqrt(n)
    J, h = vf.tangent(x), 1e-4
    E = h * np.eye(n)
    fd = ((vf(x + E) - vf(x - E)) / (2 * h)).T
    assert np.abs(J - fd).max() <= 1e-7 * np.abs(J).max()
    assert np.abs(J - J.T).max() <= 1e-13 * np.abs(J).max()
    X = np.vstack([x, -2 * x, np.roll(x, 1)])
    rows = np.vstack([vf(r)[0] for r in X])
    assert np.abs(vf(X) - rows).max() <= 1e-13 * np.abs(rows).max()


@pytest.mark.parametrize("label", SIX, ids=str)
def test_order3_is_the_modal_normal_form(shell, label):
    """T of the modal DPIM at order 3 equals the model's NF T over all its modes, to 1e-12 relative.

    Both are sums of g_s^2 over the same modes with the same denominators; they differ by the
    polarisation's round-off (~1e-15) and the order of the sums; measured <= 1.4e-15.
    """
    p = shell.index(*label)
    om = shell.omegas()
    res = modal_dpim(modal_system(shell, p), 3, shell.labels())
    nf = modal_method("nf", p, om, shell.quadratic_coefficients(p), shell.cubic_coefficient(p),
                      np.arange(len(om)), Tolerances(), shell.labels())
    assert res.T == pytest.approx(nf.T, rel=1e-12)


def truncation(shell: VonKarmanShell, labels: list[tuple[int, int]]) -> ModalSystem:
    """The von Karman model truncated to the cos modes ``labels`` (the first is the master): the Galerkin
    restriction of its force."""
    full = modal_system(shell, shell.index(*labels[0]))
    glob = [shell.index(*lab) for lab in labels]
    sub = np.asarray([int(np.flatnonzero(full.index == s)[0]) for s in glob])
    m = len(full.index)

    def forces(X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(X)
        Z = np.zeros((X.shape[0], m))
        Z[:, sub] = X
        return full.forces(Z)[:, sub]

    return ModalSystem(np.asarray(glob), 0, full.omega[sub], forces)


def test_two_mode_truncation_against_shooting(shell):
    """(0,1) with (0,2) at kappa = 25 (a softening mode): the order-15 backbone against shooting.

    At A = 0.3 and 0.45 the frequency drops by the amounts asserted (>= 2 %, >= 5 %). The reference is exact
    to ~1e-12 (DOP853 at rtol 1e-12); the DPIM's truncation error, measured as the change from order 13 to 15,
    is 8e-10 at A = 0.3 and 2.4e-7 at A = 0.45 (DPIM - shooting measured: 1e-10 and 4e-8): 1e-5 covers it
    with room for other BLAS (the sums are of O(1) terms, round-off 1e-14).
    """
    sysm = truncation(shell, [(0, 1), (0, 2)])
    res = modal_dpim(sysm, 15, shell.labels())
    w = float(sysm.omega[0])
    m = len(sysm.omega)
    sh = Shooting(np.eye(m), np.diag(sysm.omega ** 2), lambda x: sysm.forces(x)[0], np.eye(m)[0], w)
    shifts = []
    for A in (0.3, 0.45):
        orb = sh.at_amplitude(A)
        shifts.append(1 - orb.omega / w)
        assert res.backbone().omega_at(A)[0] == pytest.approx(orb.omega, rel=1e-5)
    assert shifts[0] >= 0.02 and shifts[1] >= 0.05


def scene(tmp_path, backbone: str, masters: str = '["(2,0)", "(0,1)"]'):
    import tomllib

    text = (f'[model]\nsolver = "vonkarman"\nkappa = 25.0\nk_max = 4\nn_transverse = 4\n[analysis]\n'
            f'master_modes = {masters}\nmethods = ["nf"]\n[analysis.backbone]\n{backbone}'
            f'[output]\ndir = "out"\n')
    return parse_scene(tomllib.loads(text), file=tmp_path / "s.toml", base_dir=tmp_path, text=text)


def test_run_gives_the_backbone_block(tmp_path):
    """The modal run fills each master's backbone block (as the adapter path) and the HDF5 arrays; W_max/h at
    the asked values is reached to the root finder's 1e-13 (relative), and the frequencies are those of
    :func:`modal_dpim` called directly (the same arithmetic: equal to round-off, 1e-12)."""
    sc = scene(tmp_path, "order = 5\nw_over_h = [0.2, 0.5]\n")
    model = VonKarmanShell(kappa=25.0, k_max=4, n_transverse=4)
    res = run_modal_model(sc, model, Progress(enabled=False))
    for rec in res.modes:
        b = rec.backbone
        assert b["order"] == 5 and set(b) >= {"amplitude", "omega", "omega_ratio", "w_max_over_h",
                                              "valid_up_to", "flags", "counts", "modes"}
        assert b["w_max_over_h"] == pytest.approx([0.2, 0.5], rel=1e-10)
        direct = modal_dpim(modal_system(model, rec.index), 5, model.labels()).backbone()
        assert b["omega"] == pytest.approx(list(direct.omega_at(b["amplitude"])), rel=1e-12)
        assert rec.methods["nf"].T == pytest.approx(res.backbones[rec.index].T, rel=1e-12)
        for key in ("index", "Y", "c", "modes", "omega", "w_max_over_h"):
            assert f"backbone_{rec.index}_{key}" in res.arrays
    # the files of a run: strict JSON, and the HDF5 document and arrays read back
    doc = json.loads(res.to_json())
    assert doc["modes"][0]["backbone"]["order"] == 5
    stored = read_hdf5(write_hdf5(res, tmp_path / "r.h5"))
    assert stored["modes"][1]["backbone"]["w_max_over_h"] == pytest.approx([0.2, 0.5], rel=1e-10)
    p = res.modes[0].index
    assert np.array_equal(stored["arrays"][f"backbone_{p}_Y"], res.arrays[f"backbone_{p}_Y"])


class NoForces(ModalModel):
    name = "noforces"

    def omegas(self):
        return np.array([1.0, 2.5])

    def quadratic_coefficients(self, p):
        return np.zeros(2)

    def cubic_coefficient(self, p):
        return 1.0


def test_model_without_forces_is_refused(tmp_path):
    """A modal model that gives only g^s_pp and h^p_ppp: a SceneError on analysis.backbone, not a traceback."""
    sc = scene(tmp_path, "order = 5\n", masters="[0]")
    with pytest.raises(SceneError, match="analysis.backbone"):
        run_modal_model(sc, NoForces(), Progress(enabled=False))
