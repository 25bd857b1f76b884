"""Cantilever strips (issue 31): T of the first two bending modes right against the inextensible theory, or n/a.

C3D20 strips of width 3h, one element through width and thickness, clamped at x = 0, nu = 0
(tests/helpers/cantilever.py; the theory there: Crespo da Silva & Glynn's inextensible cantilever,
single-mode Galerkin, checked against an ODE integration in tests/nf/test_cantilever_theory.py, with
the first correction for a finite axial stiffness, ``extensible=True``). The strip's first two bending
modes in z are modes 0 and 2 (mode 1 bends in y: width 3h, three times stiffer). Before issue 31 the
first mode at L/h = 300 printed T = -0.0189 ("softening", a wrong sign, shown) at the default STEP
amplitude, and at L/h = 1000 a wrong sign likewise.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from stepnf.flags import t_unusable
from stepnf.pipeline.run import run_scene
from stepnf.scene.parse import load_scene
from helpers.cantilever import E, H, NU, RHO, gamma_theory, write_strip_deck, write_strip_scene
from helpers.required import requires

#: L/h -> elements along the length (mode 2's Gamma converged to < 0.1%: bench/cantilever.py)
NX = {100: 40, 300: 80, 1000: 100}


def fenicsx_scene(folder: Path, slenderness: int, step: str = "") -> Path:
    deck = write_strip_deck(folder, slenderness, "hex20", nx=NX[slenderness])
    path = folder / f"fenicsx_{slenderness}.toml"
    path.write_text(f'[model]\nsolver = "fenicsx"\nmesh = "{deck.name}"\n\n[model.material]\nE = {E!r}\n'
                    f'nu = {NU!r}\nrho = {RHO!r}\n\n[[model.boundary]]\nset = "CLAMP"\n\n[analysis]\n'
                    f'master_modes = [0, 2]\nmethods = ["dnf"]\nthickness = {H!r}\ntransverse = "uz"\n{step}')
    return path


def gamma_error(method, r: int, slenderness: int) -> float:
    return method.gamma / gamma_theory(r, slenderness, extensible=True) - 1


@pytest.mark.fenicsx
@requires("dolfinx")
@pytest.mark.parametrize("slenderness", [100, 300, 1000])
def test_both_bending_modes_within_3_percent(tmp_path, slenderness):
    """Measured (Gamma against the theory with the axial-stiffness correction), modes 0 and 2: L/h = 100:
    +1.15% and -0.06%; L/h = 300: +0.95% and -0.08%; L/h = 1000: +2.4% and -0.4%, each with a forces' and
    solves' error estimate below 1e-7 (the eigenvalue's part: below): the rest is the model (the first mode's T
    is a 15-fold cancellation of curvature stiffening against axial inertia, so shear, rotary inertia and the
    mesh show there ~10 times larger than in each term). 3% is the issue's target. Before issue 31: a wrong
    sign at L/h = 300 and 1000. Issue 35 (refined eigen-solve): mode 0 at L/h = 1000 is +3.7%, the model's own
    error at 100 elements: the +2.4% before held ~1.3% of eigenvalue error (w1 4.4e-4 above the exact Rayleigh
    quotient of its own vector, now 2.5e-6; T moves ~15 times the relative error of lambda there). With 200
    elements (measured once, 2026-12-06): mode 0 +0.35%, mode 2 -0.025%: the 3% holds on a finer mesh, kept at
    100 elements for the suite's time."""
    res = run_scene(load_scene(fenicsx_scene(tmp_path, slenderness)), write=False)
    for m, r in zip(res.modes, (1, 2)):
        dnf = m.methods["dnf"]
        assert t_unusable(dnf) is None, (m.index, dnf.flags)
        target = 0.03
        if (slenderness, r) == (1000, 1):
            # double precision resolves this mode's eigenvalue only to ~6e-3 (the run's note: a solid model of a
            # strip 1000 times longer than thick) and T moves 15 times lambda's error: the run says so (t_roundoff,
            # T_error 9.0e-2) and its Gamma moves with the rounding (+3.7% on one machine; +3.93% / +4.11% on
            # another with the default / one BLAS thread, omega 5.6e-5 apart): right within the model's 3% plus
            # the error the run states, and flagged (issue 31: right or flagged)
            assert "t_roundoff" in {f["kind"] for f in dnf.flags}, dnf.flags
            target += dnf.T_error
        assert abs(gamma_error(dnf, r, slenderness)) < target, (m.index, dnf.gamma, dnf.T_error)
    # the first mode's digits came from STEP along the quadratic manifold (module stepnf/step/manifold_probe)
    assert "manifold_probe" in {f["kind"] for f in res.modes[0].methods["dnf"].flags}
    # T_error also holds the master's own eigenvalue error through T's slope in lambda (issue 31 item 2,
    # nf/roundoff.eigenvalue_part: measured 7.5e-4 at L/h = 300, 9.1e-2 at 1000, against an actual error of
    # +0.95% and +2.4% model included); the forces' and solves' part stays below 1e-4
    first = res.modes[0].methods["dnf"]
    assert first.T_error - first.extra["roundoff_dT_lambda"] / abs(first.T) < 1e-4


@pytest.mark.fenicsx
@requires("dolfinx")
def test_an_amplitude_the_user_fixed_is_kept(tmp_path):
    """``relative_amplitude = 0.5`` given: no raise; the STEP at +-q phi gives the first mode's T with a
    wrong sign there (measured -0.026 against +0.00124, its bound 16: never shown), STEP along the
    manifold at the same amplitude gives it at +1.0% (error estimate 1.6e-4)."""
    scene = fenicsx_scene(tmp_path, 300, "\n[analysis.step]\nrelative_amplitude = 0.5\n")
    res = run_scene(load_scene(scene), write=False)
    first, second = (m.methods["dnf"] for m in res.modes)
    assert not any(f["kind"] == "step_amplitude_raised" for f in first.flags + second.flags)
    assert first.extra["T_first"] < 0 < first.T  # the STEP's wrong sign, replaced
    for dnf, r in ((first, 1), (second, 2)):
        assert t_unusable(dnf) is None and abs(gamma_error(dnf, r, 300)) < 0.03


@pytest.mark.calculix
@requires("ccx")
def test_calculix_strip_second_mode_along_the_manifold(tmp_path):
    """CalculiX prints forces with 7 digits: at L/h = 300 the STEP at +-q phi leaves mode 2's T 15% off
    even at the raised amplitude (bound 7.9); STEP along the quadratic manifold gives it to +0.11%
    (measured; error estimate 0.14). Mode 0 stays n/a (estimate 10: 7 digits cannot resolve its double
    cancellation)."""
    deck = write_strip_deck(tmp_path, 300, "hex20", nx=NX[300])
    res = run_scene(load_scene(write_strip_scene(deck, masters=(0, 2))), write=False)
    first, second = (m.methods["dnf"] for m in res.modes)
    assert t_unusable(first) is not None
    assert "manifold_probe" in {f["kind"] for f in second.flags}
    assert t_unusable(second) is None and abs(gamma_error(second, 2, 300)) < 0.03
