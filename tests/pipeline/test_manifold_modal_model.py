"""``[analysis.backbone] manifolds`` on a model in modal coordinates: the von Karman model of the kappa = 25 cap
(the model of docs/backbone/kappa25.md's von Karman columns, default truncation; issue 33, items 3 and 5).

References: the single-mode modal DPIM of the same master (stepnf.pipeline.modal_coordinates.modal_dpim), whose
orders N and N + 2 measure its own truncation; the model's frequency ratios (w(4,1)/w(2,1) = 1.9353,
w(0,2)/w(4,0) = 1.9073), against the resonance tolerance |2 - r| / 2; the symmetry of the model (a cos mode of k_p
nodal diameters drives the cos modes of k = j k_p only: stepnf.pipeline.modal_forces).
"""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.dpim.multimode.backbone import backbone_branches, omega_at
from stepnf.models.vonkarman import VonKarmanShell
from stepnf.pipeline.modal_coordinates import modal_dpim
from stepnf.pipeline.modal_forces import modal_system
from stepnf.pipeline.modal_manifolds import Subspaces, modal_manifold, modal_plans
from stepnf.scene.parse import parse_scene

#: Global indices of the default kappa = 25 model's modes (labels checked in the fixture).
M20, M30, M40, M21, M02, M41, M21_SIN = 0, 2, 5, 11, 13, 22, 12


@pytest.fixture(scope="module")
def cap():
    model = VonKarmanShell(kappa=25.0)
    labels = model.labels()
    assert [labels[i] for i in (M20, M30, M40, M21, M02, M41, M21_SIN)] == [
        (2, 0), (3, 0), (4, 0), (2, 1), (0, 2), (4, 1), (2, 1)]
    assert model.companions()[M21_SIN] == "sin"
    return model, labels, np.asarray(model.omegas(), dtype=float)


def vk_scene(masters: list, backbone: dict):
    return parse_scene({"model": {"solver": "vonkarman", "kappa": 25.0},
                        "analysis": {"master_modes": masters, "methods": ["dnf"], "backbone": backbone},
                        "output": {"dir": "out"}}, file=Path("vk.toml"))


def plans_of(cap, masters: list, backbone: dict):
    model, labels, omega = cap
    scene = vk_scene([f"({k},{n})" for k, n in masters], backbone)
    return modal_plans(scene, model, omega, labels, [model.index(*m) for m in masters], Subspaces(model))


def test_subspace_holding_the_set(cap):
    """The manifold lies in the subspace of the mode of its set that holds them all: (2,1) (k = 2) holds (4,1)
    (k = 4); (4,0) (k = 4) holds (0,2) (k = 0), not the other way round; (2,0) and (3,0), or (2,1) and its sin
    twin, lie in no common subspace."""
    sub = Subspaces(cap[0])
    assert sub.holder((M21, M41)) == M21 and sub.holder((M02, M40)) == M40 and sub.holder((M40, M02)) == M40
    assert sub.holder((M20, M30)) is None and sub.holder((M21, M21_SIN)) is None
    assert sub.is_sin(M21_SIN) and not sub.is_sin(M21)


def test_transverse_field_of_complex_coefficients(cap):
    """A manifold's fields W[alpha] are complex: the subspace's transverse map (linear, real) keeps their imaginary
    part (it was cast to float: W_max/h of the real parts only)."""
    op = modal_system(cap[0], M21).transverse
    Y = np.random.default_rng(0).standard_normal((40, 3)) + 1j * np.random.default_rng(1).standard_normal((40, 3))
    whole, re, im = op(Y), op(Y.real), op(Y.imag)
    assert np.iscomplexobj(whole) and np.allclose(whole, re + 1j * im, rtol=0, atol=1e-12 * np.abs(whole).max())


def test_auto_picks_the_one_to_two_partners(cap):
    """"auto" at order 3 (harmonics up to 3: the 1:2 resonances): (4,1) for (2,1) (|2 - 1.9353| / 2 = 0.032) and
    (0,2) for (4,0) (|2 - 1.9073| / 2 = 0.046) within the default tolerance 0.05, and says why; (0,2) as a master
    adds nothing (no mode of its axisymmetric subspace near 1:2..1:3 of it: (0,3) at 2.134, 0.067 off). The
    tolerance is that relative distance: 0.045 drops (0,2) (0.0464 off), 0.047 keeps it. At order 5 the 1:4
    resonances join ((2,3) at 3.960 and (0,4) at 4.050 w of (2,1), (0,3) at 4.070 w of (4,0))."""
    got = plans_of(cap, [(2, 1), (4, 0), (0, 2)], {"order": 3, "manifolds": "auto"})
    assert [p.modes for p in got] == [(M21, M41), (M40, M02)] and {p.chosen for p in got} == {"auto"}
    assert "mode 22 near 2 x w of mode 11 (w_s/w_p = 1.9353)" in got[0].why
    assert "mode 13 near 2 x w of mode 5 (w_s/w_p = 1.9073)" in got[1].why and "tolerance 0.05" in got[1].why
    tight = plans_of(cap, [(2, 1), (4, 0)], {"order": 3, "manifolds": "auto", "resonance": 0.045})
    assert [p.modes for p in tight] == [(M21, M41)]
    loose = plans_of(cap, [(2, 1), (4, 0)], {"order": 3, "manifolds": "auto", "resonance": 0.047})
    assert [p.modes for p in loose] == [(M21, M41), (M40, M02)]
    five = plans_of(cap, [(2, 1), (4, 0)], {"order": 5, "manifolds": "auto"})
    assert [p.modes for p in five] == [(M21, M41, 41, 43), (M40, M02, 28)]
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        assert plans_of(cap, [(2, 1)], {"order": 3, "manifolds": "auto", "resonance": 0.03}) == []
    assert any("no master has a mode near" in str(w.message) for w in seen)


def test_manifold_continues_the_single_mode_backbone(cap):
    """On the manifold of (2,1) and (4,1) (1:2, order 5), the branch that continues (2,1) is the family of periodic
    orbits the single-mode DPIM parametrises (unique: w(4,1)/w(2,1) is not an integer), so at small amplitude both
    give the same w_NL/w up to their truncations. Measured (this model, A of X_(2,1)): the difference is 2.8e-11,
    1.8e-9, 1.1e-7 at A = 0.01, 0.02, 0.04 (w_NL/w - 1 = 1.3e-5 .. 2.1e-4), growing as A^6 (x 63.6, 63.0 per
    doubling: the first neglected order of an order-5 frequency series), and below the single-mode series' own
    truncation, |orders 7 - 5| = 3.1e-11, 2.0e-9, 1.3e-7. Asserted: below that truncation, and A^6 within 10 %."""
    model, labels, omega = cap
    scene = vk_scene(["(2,1)"], {"order": 5, "manifolds": [["(2,1)", "(4,1)"]]})
    sub = Subspaces(model)
    [plan] = modal_plans(scene, model, omega, labels, [M21], sub)
    man, system = modal_manifold(scene, model, plan, sub.holder(plan.modes), labels)
    assert man.masters == (M21, M41) and list(man.ratios) == [1, 2] and len(system.index) == 40
    assert all(f["mode"] in system.index for f in man.flags)  # renumbered to the model's modes
    [main_branch] = [b for b in backbone_branches(man, 0, 0.1, r0=0.001, tol=None)
                     if b.kind == f"continues mode {M21}"]
    single = {n: modal_dpim(modal_system(model, M21), n, labels) for n in (5, 7)}

    def ratio(n: int, A: float) -> float:
        bb = single[n].backbone()
        return float(bb.frequency(bb.rho_at(A)) / single[n].omega)
    diffs = []
    for A in (0.01, 0.02, 0.04):
        d = omega_at(man, main_branch, A) / float(man.omega[0]) - ratio(5, A)
        assert abs(d) <= abs(ratio(7, A) - ratio(5, A)), A
        diffs.append(abs(d))
    assert np.allclose(np.asarray(diffs[1:]) / np.asarray(diffs[:-1]), 2.0 ** 6, rtol=0.1)


@pytest.mark.parametrize("sets, key, says", [
    ('[["(2,0)", "(3,0)"]]', "manifolds[0]", "are not coupled by symmetry"),
    (f'[[{M21}, {M21_SIN}]]', "manifolds[0]", f"mode {M21_SIN} (2, 1) is a sin companion"),
    ('[["(2,1)", "(4,1)"]]\nratios = [[1, 3]]', "ratios[0]", "modes [11 (2, 1), 22 (4, 1)]: ratios [1, 3] do not"),
])
def test_uncoupled_set_is_a_scene_error(tmp_path, capsys, sets, key, says):
    """A set no invariant subspace of the model holds: one line naming the set's key, exit 2, before any DPIM (and
    ratios that do not fit the frequencies, with the model's mode numbers, not the subspace's)."""
    path = tmp_path / "vk.toml"
    path.write_text('[model]\nsolver = "vonkarman"\nkappa = 25.0\n[analysis]\nmaster_modes = ["(2,0)", "(2,1)"]\n'
                    f'methods = ["dnf"]\n[analysis.backbone]\norder = 5\nmanifolds = {sets}\n[output]\ndir = "out"\n')
    assert main(["run", str(path), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"[analysis.backbone.{key}]" in err and says in err
    assert "Traceback" not in err


@pytest.mark.slow  # ~12 s of CPU, ~25 s on a loaded machine: W_max/h on the model's polar grid at every branch point
def test_run_writes_the_manifold_blocks(tmp_path, capsys):
    """A run with (2,1) on its 1:2 manifold and (2,0) single-mode: (2,1)'s block has the adapters' keys (backbone
    + manifold + branch + coupled_branches) with W_max/h reached where asked (the root of W_max/h - target, to
    round-off), and the subspace's modes; HDF5 the manifold's coefficients and branches once; (2,0) as without
    manifolds."""
    path = tmp_path / "vk.toml"
    path.write_text('[model]\nsolver = "vonkarman"\nkappa = 25.0\n[analysis]\nmaster_modes = ["(2,1)", "(2,0)"]\n'
                    'methods = ["dnf"]\n[analysis.backbone]\norder = 3\nw_over_h = [0.05, 0.1]\n'
                    'manifolds = [["(2,1)", "(4,1)"]]\n[output]\ndir = "out"\n')
    assert main(["run", str(path), "--json", "-q"]) == 0
    doc = {m["index"]: m["backbone"] for m in json.loads(capsys.readouterr().out)["modes"]}
    b = doc[M21]
    assert b["manifold"]["modes"] == [M21, M41] and b["manifold"]["ratios"] == [1, 2]
    assert b["manifold"]["stored_with"] == M21 and b["branch"]["kind"] == f"continues mode {M21}"
    assert b["coupled_branches"] and np.allclose(b["w_max_over_h"], [0.05, 0.1], rtol=1e-9)
    # w_NL/w - 1 ~ T A^2 at these sizes: positive (hardening, as T = +0.13) and about 4x from W/h 0.05 to 0.1
    shift = np.asarray(b["omega_ratio"]) - 1.0
    assert np.all(shift > 0) and 3.5 < shift[1] / shift[0] < 4.0
    assert len(b["modes"]) == 40 and M41 in b["modes"] and "manifold" not in doc[M20]
    with h5py.File(tmp_path / "out" / "vk.h5") as f:
        a = f["arrays"]
        assert list(a[f"backbone_{M21}_modes"][()]) == b["modes"]
        assert a[f"backbone_{M21}_manifold_W_re"].shape[1] == 40
        assert list(a[f"backbone_{M21}_branch0_masters"][()]) == [M21, M41]
        assert f"backbone_{M20}_manifold_W_re" not in a
