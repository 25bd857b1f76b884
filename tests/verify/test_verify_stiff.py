"""``stepnf verify`` on a stiff model (issue 29, finding 8): an implicit integrator, and a progress line.

The 2-dof system of tests/helpers/systems.stiff_two_dof at ratio 1e6 (modal frequencies 1, the master, and 1050):
DOP853 (explicit, rtol 1e-12) is bounded by its stability to steps of ~3.3 / 1050 and took minutes
(tens of thousands of force evaluations per orbit). The shooting now integrates it by Gauss-Legendre
collocation (stepnf.verify.collocation), 32 steps per period whatever the stiffness. Timings are in
bench/verify_stiff.py; here the work is bounded instead (the number of force fields the model is
asked for, deterministic), and the orbits' frequencies are checked against two references.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.linalg as sla
from scipy.integrate import quad
from scipy.optimize import brentq

from stepnf.cli.main import main
from stepnf.verify.collocation import GaussLegendre
from stepnf.verify.periodic import Shooting
from stepnf_polynomial.adapter import PolynomialAdapter, save_system
from helpers.scenes import TWO_DOF_SCENE
from helpers.systems import stiff_two_dof

#: Force fields a whole ``verify --amplitudes 0.4 0.8`` of the ratio-1e6 system may ask for: the scene's
#: backbone run (STEP and DPIM order 21: 7,858) and the two orbits (measured 2,083 and 6,660; the
#: explicit DOP853 of before asked for more than 25,000 in its first orbit, then ran for minutes).
MAX_FIELDS = 25_000


def reduced_frequency(A: float) -> float:
    """The master's frequency at amplitude ``A`` (of ``q``, ``(max - min) / 2``) for an infinitely stiff
    second mode: ``q'' + q + 0.1 q^2 + 0.5 q^3 = 0`` (stiff_two_dof's modal terms of the master alone),
    period ``2 int dq / sqrt(2 (E - V))`` between the turning points, by Gauss-Jacobi quadrature."""
    V = lambda q: q * q / 2 + 0.1 * q ** 3 / 3 + 0.5 * q ** 4 / 4  # noqa: E731

    def turning(b: float) -> float:  # the negative turning point at the energy of the positive one b
        return brentq(lambda q: V(q) - V(b), -3 * b, 0.0, xtol=1e-16)

    b = brentq(lambda b: (b - turning(b)) / 2 - A, 0.5 * A, 2 * A, xtol=1e-16)
    a, E = turning(b), V(b)
    # E - V(q) = (q - a)(b - q) Q(q): Q the quartic's quotient by its two real roots (remainder ~1e-17)
    Q, _ = np.polydiv(np.array([0.5 / 4, 0.1 / 3, 0.5, 0.0, -E]), np.poly([a, b]))
    g = lambda q: 1.0 / np.sqrt(2 * np.polyval(Q, q))  # noqa: E731  smooth on [a, b]
    half, _ = quad(g, a, b, weight="alg", wvar=(-0.5, -0.5), epsabs=1e-15, epsrel=1e-14)
    return np.pi / half


def write_scene(folder, ratio: float):
    save_system(folder / "two_dof.npz", *stiff_two_dof(ratio))
    path = folder / "scene.toml"
    path.write_text(TWO_DOF_SCENE.format(backbone="\n[analysis.backbone]\norder = 21\npoints = 4\n"))
    return path


def test_stiff_ratio_1e6_verifies_with_bounded_work(tmp_path, capsys, monkeypatch):
    """Two orbits of the ratio-1e6 system, with a bounded number of force evaluations, agreeing with the
    backbone and with the reduced 1-dof oscillator; the progress line names the orbits and estimates.

    References: DPIM order 21 (its truncation at A = 0.8 is 4.07e-8, the same for ratios 1e2, 1e4, 1e6
    and by DOP853 at 1e4, bench/verify_stiff.py: bound 1e-6; at A = 0.4 measured 3e-13: bound 1e-10);
    the reduced oscillator neglects the slaved second mode, ``q_1 ~ 0.05 q^2 / 1050^2``, whose coupling
    moves the frequency by ~2 * 0.05 * q_1 / q ~ 3e-9 (measured 2e-9): bound 1e-7.
    """
    fields = {"n": 0}
    plain = PolynomialAdapter._internal_forces

    def counted(self, U):
        fields["n"] += len(U)
        if fields["n"] > MAX_FIELDS:  # stops the explicit integration of old quickly, as a failure
            raise RuntimeError(f"more than {MAX_FIELDS} force evaluations")
        return plain(self, U)
    monkeypatch.setattr(PolynomialAdapter, "_internal_forces", counted)
    code, out, err = main(["verify", str(write_scene(tmp_path, 1e6)), "--amplitudes", "0.4", "0.8", "--json"]), \
        *capsys.readouterr()
    assert code == 0, err
    assert fields["n"] <= MAX_FIELDS
    (mode,) = json.loads(out)["modes"]
    for c, tol in zip(mode["checks"], (1e-10, 1e-6)):
        assert c["work"]["method"] == "implicit"
        assert c["work"]["stiffness_ratio"] == pytest.approx(1050, rel=1e-9)
        assert abs(c["relative_difference"]) < tol, c
        assert c["omega_check"] == pytest.approx(reduced_frequency(c["orbit_amplitude"]), rel=1e-7)
    # the progress line (stderr, not a TTY here: printed as `stepnf run` does, --quiet silences it)
    lines = [line for line in err.splitlines() if "orbit" in line and " of 2 " in line]
    assert len(lines) == 2, err
    assert "master mode 0, A = 0.4: orbit 1 of 2 (elapsed" in lines[0] and "estimate after the first" in lines[0]
    assert "master mode 0, A = 0.8: orbit 2 of 2 (elapsed" in lines[1] and "s left)" in lines[1]
    assert "verify: 2 orbits in" in err


def shooting(ratio: float, integrator: str = "auto") -> Shooting:
    """Shooting on stiff_two_dof(ratio) with plain numpy forces (fast calls: DOP853 stays affordable)."""
    M, K, G, H = stiff_two_dof(ratio)
    forces = lambda U: (U @ K.T + np.einsum("ijk,mj,mk->mi", G, U, U)  # noqa: E731
                        + np.einsum("ijkl,mj,mk,ml->mi", H, U, U, U))
    tangent = lambda u: K + 2 * np.einsum("ijk,j->ik", G, u) + 3 * np.einsum("ijkl,j,k->il", H, u, u)  # noqa: E731
    lam, V = sla.eigh(K, M)
    return Shooting(M, K, lambda u: forces(u[None])[0], V[:, 0], np.sqrt(lam[0]), forces=forces, tangent=tangent,
                    integrator=integrator)


@pytest.mark.parametrize("ratio", [1e2])
def test_implicit_and_explicit_shooting_agree(ratio):
    """At ratio 1e2 (DOP853 still affordable here: 1e4 takes a minute) both integrators find the same orbit,
    from the linear guess through a continuation: frequency to 1e-11 (DOP853's rtol 1e-12 over half a
    period, the implicit order-16 scheme's phase error ~1e-13 at 32 steps a period; measured 7e-14 at
    ratio 1e4, A = 0.8, bench/verify_stiff.py), the explicit asking for more force fields."""
    orbits, work = {}, {}
    for integ in ("explicit", "implicit"):
        sh = shooting(ratio, integ)
        assert sh.method == integ
        orbits[integ] = sh.at_amplitude(0.6, steps=3)
        work[integ] = sh.work
    assert orbits["implicit"].omega == pytest.approx(orbits["explicit"].omega, rel=1e-11)
    assert work["implicit"]["force_evaluations"] < work["explicit"]["force_evaluations"]


def test_auto_choice_from_the_spectrum():
    """``auto``: explicit below STIFF_RATIO (the non-stiff systems of the other tests keep DOP853 and
    their numbers), implicit above it."""
    for ratio, method in ((1.0, "explicit"), (1e2, "implicit"), (1e6, "implicit")):
        sh = shooting(ratio)
        assert sh.method == method, (ratio, sh.stiffness_ratio)
    with pytest.raises(ValueError, match="integrator must be one of"):
        Shooting(np.eye(1), np.eye(1), lambda x: x, np.array([1.0]), 1.0, integrator="rk4")


def test_sensitivities_are_those_of_the_discrete_map():
    """The implicit run's derivatives of the end state with respect to x0 and t_end equal central
    differences of the same discrete map (Richardson over two increments: error ~1e-9, bound 1e-7),
    on a stiff linear-plus-cubic 2-dof system where a continuous-time Jacobian would differ."""
    M = np.diag([1.0, 2.0])
    K = np.array([[2.0, -1.0], [-1.0, 1e4]])
    f = lambda U: U @ K.T + 0.3 * np.atleast_2d(U) ** 3  # noqa: E731
    tan = lambda x: K + np.diag(0.9 * x ** 2)  # noqa: E731
    gl = GaussLegendre(M, K, f, tangent=tan)
    x0, v0 = np.array([0.7, 0.01]), np.zeros(2)
    r = gl.run(x0, v0, 2.0, 12, sensitivity=True)

    def end(dx=np.zeros(2), dt=0.0):
        q = gl.run(x0 + dx, v0, 2.0 + dt, 12)
        return np.concatenate([q.x, q.v])
    for col in range(3):
        def fd(e):
            d = np.zeros(2)
            if col < 2:
                d[col] = e
                return (end(dx=d) - end(dx=-d)) / (2 * e)
            return (end(dt=e) - end(dt=-e)) / (2 * e)
        ref = (4 * fd(5e-4) - fd(1e-3)) / 3
        assert np.allclose(r.S[:, col], ref, rtol=1e-7, atol=1e-7 * np.abs(ref).max()), (col, r.S[:, col], ref)


def test_too_coarse_implicit_steps_are_refined():
    """Started at 6 steps a period (w h ~ 2 at this amplitude), the a-posteriori check (the orbit integrated at twice the
    steps) doubles them until the residual is below 1e-11: the strongly hardening Duffing orbit
    (x'' + x + x^3, A = 2, w_NL / w = 1.9) then matches its exact frequency (by quadrature of the
    reduced_frequency kind, here the elliptic K) to 1e-10, as DOP853 does (tests/verify/test_periodic.py)."""
    from scipy.special import ellipk

    f = lambda x: x + x ** 3  # noqa: E731
    sh = Shooting(np.eye(1), np.eye(1), f, np.array([1.0]), 1.0, tangent=lambda x: np.diag(1 + 3 * x ** 2),
                  integrator="implicit", steps=6)
    orb = sh.at_amplitude(2.0)
    m = 4.0 / (2 * (1 + 4.0))
    assert sh.steps > 6 and orb.residual < 1e-11  # measured: 12 steps, residual 2e-13
    assert orb.omega == pytest.approx(np.pi * np.sqrt(5.0) / (2 * ellipk(m)), rel=1e-10)
