"""The FRC's measures over arrays of points (``Backbone.amplitudes``, ``w_max_many``, ``Averaged.extremes_many``,
``amplitude_shift_many``, ``jacobian`` / ``stable`` on arrays) against references computed another way: the
series summed on a dense phase grid, the averaging's change of variables integrated by quadrature, the Jacobian by
finite differences of the averaged vector field. (Their one-point forms wrap them, or they wrap the one-point
forms: a comparison between the two would test nothing.)

Systems: examples/polynomial_frc.toml's (``random_system(12, seed=3)``, mode 0, order 11, modal xi = 0.002,
kappa = 6e-4: a curve that bends right with two folds; the extremes of ``q`` at theta = 0 and pi), and a made-up
parametrisation with random coefficients whose extremes lie inside (0, pi), where Newton's refinement matters.

Dense-grid tolerances: a grid of spacing ``d`` samples within ``d / 2`` of an extremum of ``f = sum_m c_m cos(m t)``,
so its best sample is below the extremum by at most ``(1/2) max|f''| (d/2)^2 <= (1/2) sum_m m^2 |c_m| (d/2)^2``
(~1e-8 relative here, 2e-5 on the methods' own 64 N-point grid: an unrefined grid value fails); Newton's converged
value is at least the dense grid's best sample, less round-off (``1e-14 sum_m |c_m|``: 12 terms, a margin of 10).
"""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.dpim.parametrisation import DPIM, DPIMResult
from stepnf.forced.averaged import Averaged
from stepnf.forced.damping import Damping
from stepnf.forced.frc import forced_responses
from stepnf.forced.spec import DampingSpec
from helpers.systems import batch_force, modes, random_system

XI, KAPPA = 0.002, 6e-4
DENSE = 100_001  # phase samples on [0, pi]


def _cosines(Y: dict, N: int, rho: float) -> np.ndarray:
    """``X[m]``: the field's coefficient of ``cos(m theta)`` at amplitude ``rho`` (N + 1, n), from ``res.Y``."""
    X = np.zeros((N + 1, len(next(iter(Y.values())))))
    for (p, m), y in Y.items():
        X[m] += rho ** p * y
    return X


def _dense_check(value: float, C: np.ndarray, dense_best: float) -> None:
    """``value`` (a refined largest value of the rows' cosine series ``C`` (rows, m)) against the dense grid's."""
    ms = np.arange(C.shape[1])
    grid = 0.5 * float(np.max(np.abs(C) @ ms ** 2)) * (np.pi / (DENSE - 1) / 2) ** 2
    rnd = 1e-14 * float(np.max(np.abs(C).sum(axis=1)))
    assert dense_best - rnd <= value <= dense_best + grid + rnd, (value, dense_best, grid)


def _dense_amplitude(res: DPIMResult, rho: float) -> tuple[float, np.ndarray]:
    """``(A, c)``: ``(max q - min q) / 2`` of ``q = phi^T M x`` on the dense grid, and q's cosine coefficients."""
    c = _cosines(res.Y, res.order, rho) @ (res.M @ res.phi)
    q = c @ np.cos(np.outer(np.arange(len(c)), np.linspace(0.0, np.pi, DENSE)))
    return 0.5 * (q.max() - q.min()), c


def _dense_w_max(res: DPIMResult, rho: float, T: np.ndarray) -> tuple[float, np.ndarray]:
    """``(max_i,theta |(T x(theta))_i|, C)`` on the dense grid over all rows of ``T``, ``C`` the rows' coefficients."""
    C = T @ _cosines(res.Y, res.order, rho).T  # (rows, m)
    return float(np.abs(C @ np.cos(np.outer(np.arange(C.shape[1]), np.linspace(0.0, np.pi, DENSE)))).max()), C


@pytest.fixture(scope="module")
def curve():
    """``(res, av, bb, frc, rho, c, T)``: the parametrisation, averaged dynamics, backbone, the FRC (with W_max over
    the 300 rows of a random map ``T`` of the dofs: mixed signs, so that the bound's pruning of rows matters), and
    steady states ``(rho, c)``: both branches at 40 amplitudes up to the peak, and the folds."""
    M, K, G, H = random_system(12, seed=3)
    w, V = modes(K, M)
    phi, w0 = V[:, 0], w[0]
    res = DPIM(batch_force(K, G, H), K, M).parametrise(phi, w0, 11, probe=0.1)
    bb = res.backbone()
    d = Damping(DampingSpec(modal=XI), M, K, [(phi, w0)])
    T = np.random.default_rng(5).standard_normal((300, 12))
    fr = forced_responses(res, d, [({"kappa": KAPPA}, KAPPA)], (0.97, 1.03), backbone=bb, valid_to=0.15,
                          transverse=lambda Y: T @ Y, h=0.01)[0]
    av = Averaged(res, d, XI, KAPPA * (M @ phi))
    r = fr.peak["rho"] * np.linspace(0.02, 1.0, 40)
    fold_r = np.asarray([f["rho"] for f in fr.folds])
    fold_c = (np.asarray([f["Omega"] for f in fr.folds]) - av.Od(fold_r)) / av.gain(fold_r)
    rho = np.concatenate([r, r, fold_r])
    c = np.concatenate([-av.cos_abs(r), av.cos_abs(r), fold_c])
    return res, av, bb, fr, rho, c, T


@pytest.fixture(scope="module")
def made_up():
    """``(res, av, bb, rho, F)``: a parametrisation of order 7 on 30 dofs with random coefficients (``Y[p, m]`` of size
    ``0.5^(p - 1)``, M = I), damping ``C = 0.02 I``, a random force, amplitudes up to 1.5."""
    rng = np.random.default_rng(7)
    n, N = 30, 7
    phi = rng.standard_normal(n)
    phi /= np.linalg.norm(phi)
    Y = {(p, m): (phi if (p, m) == (1, 1) else 0.5 ** (p - 1) * rng.standard_normal(n))
         for p in range(1, N + 1) for m in range(p % 2, p + 1, 2)}
    res = DPIMResult(omega=1.0, phi=phi, M=np.eye(n), order=N, Y=Y, c=np.array([0.05, -0.01, 0.002]))
    F = rng.standard_normal(n)
    av = Averaged(res, lambda V: 0.02 * V, 0.02, F)
    return res, av, res.backbone(), np.linspace(0.05, 1.5, 30), F


def test_the_curve_has_folds_and_both_stabilities(curve):
    """The checks below cover what they should: two folds, stable and unstable points on the curve."""
    fr = curve[3]
    assert len(fr.folds) == 2
    assert fr.stable.any() and not fr.stable.all()


@pytest.mark.parametrize("system", ["curve", "made_up"])
def test_amplitudes_against_a_dense_grid(system, request):
    """``Backbone.amplitudes`` against ``(max q - min q) / 2`` on 1e5 phases (module docstring's tolerance, applied
    to the maximum and the minimum: A is half their difference)."""
    got = request.getfixturevalue(system)
    res, rho = got[0], got[4] if system == "curve" else got[3]
    got = res.backbone().amplitudes(rho)
    for r, A in zip(rho, got):
        ref, c = _dense_amplitude(res, r)
        _dense_check(A, c[None, :], ref)


def test_extremes_phases_against_a_dense_grid(made_up):
    """``Averaged.extremes_many``: q at the phases is q's largest and smallest value on 1e5 phases, to the grid's
    tolerance; on this system most extremes are inside (0, pi) (Newton moved them off the methods' grid)."""
    res, av, _, rho, _ = made_up
    tmax, tmin = av.extremes_many(rho)
    inside = (tmax > 1e-3) & (tmax < np.pi - 1e-3) | (tmin > 1e-3) & (tmin < np.pi - 1e-3)
    assert inside.sum() >= 10
    for r, a, b in zip(rho, tmax, tmin):
        _, c = _dense_amplitude(res, r)
        q = c @ np.cos(np.outer(np.arange(len(c)), np.linspace(0.0, np.pi, DENSE)))
        ms = np.arange(len(c))
        _dense_check(float(c @ np.cos(ms * a)), c[None, :], q.max())
        _dense_check(-float(c @ np.cos(ms * b)), -c[None, :], -q.min())


def test_w_max_against_a_dense_grid(curve, made_up):
    """``Backbone.w_max_many`` (its rows pruned by a bound, refined by Newton) against the largest ``|x_i|`` over
    all rows and 1e5 phases, rows given by a map (random, 300 and 200 rows) and by index; also the FRC's
    ``w_max_h`` (h = 0.01) at its points."""
    res, _, bb, fr, rho, _, T = curve
    for R, rows in ((T, lambda Y: T @ Y), (np.eye(12)[::2], np.arange(0, 12, 2))):
        for r, W in zip(rho[::4], bb.w_max_many(rho[::4], rows)):
            _dense_check(W, *_dense_w_max(res, r, R)[::-1])
    pick = np.arange(0, len(fr.rho), 25)
    for r, W in zip(fr.rho[pick], fr.w_max_h[pick]):
        ref, C = _dense_w_max(res, r, T)
        _dense_check(0.01 * W, C, ref)
    res, _, bb, rho, _ = made_up
    T2 = np.random.default_rng(2).standard_normal((200, 30))
    for R, rows in ((T2, lambda V: T2 @ V), (np.eye(30)[::3], np.arange(0, 30, 3))):
        for r, W in zip(rho, bb.w_max_many(rho, rows)):
            _dense_check(W, *_dense_w_max(res, r, R)[::-1])


def test_amplitude_shift_against_quadrature(made_up):
    """``Averaged.amplitude_shift_many`` against its definition integrated numerically: ``u`` the zero-mean
    antiderivative of ``(I'(theta) - mean) / Omega_d``, ``I' = v^T (F cos(theta - psi) - C v) / Omega_d`` on the
    orbit ``x = sum_m X_m cos(m theta)``, ``v = -Omega_d sum_m m X_m sin(m theta)`` (C = 0.02 I, F and X_m from the
    fields), then ``dA = (1/2)[q_I u](theta_max) - (1/2)[q_I u](theta_min)``, ``q_I = (dq/drho) / I'(rho)``, at random
    branches and phases. Trapezoid sums on 2e5 steps over the period and linear interpolation at the phases:
    error ~ d^2 max|u''| / 8 ~ 1e-9 of u (measured: 8e-10 of the largest shift); asserted to 1e-7."""
    res, av, _, rho, F = made_up
    rng = np.random.default_rng(1)
    c = rng.uniform(-1.0, 1.0, len(rho))
    th = rng.uniform(0.0, np.pi, (2, len(rho)))
    got = av.amplitude_shift_many(rho, c, *th)
    t = np.linspace(0.0, 2 * np.pi, 200_001)
    ms = np.arange(res.order + 1)
    ref = []
    for r, ci, a, b in zip(rho, c, *th):
        psi = np.arctan2(float(av.sin_psi(r)), -ci)
        X, Od = _cosines(res.Y, res.order, r), float(av.Od(r))
        v = -Od * (np.sin(np.outer(t, ms)) * ms) @ X  # (t, n)
        P = (v @ F * np.cos(t - psi) - 0.02 * np.einsum("tn,tn->t", v, v)) / Od
        P -= np.trapz(P, t) / (2 * np.pi)
        U = np.concatenate([[0.0], np.cumsum(0.5 * (P[1:] + P[:-1]) * np.diff(t))]) / Od
        u = U - np.trapz(U, t) / (2 * np.pi)
        dX = _cosines({k: k[0] * y for k, y in res.Y.items() if k[0] > 0}, res.order, r) / r  # dX_m / drho
        qI = lambda x: float(np.cos(ms * x) @ (dX @ res.phi)) / float(av.dI(r))  # noqa: E731 (M = I)
        ref.append(0.5 * (qI(a) * np.interp(a, t, u) - qI(b) * np.interp(b, t, u)))
    ref = np.asarray(ref)
    assert np.abs(ref).max() > 1e-3  # a shift that matters
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-7 * np.abs(ref).max())


def test_jacobian_and_stability_against_finite_differences(curve):
    """``Averaged.jacobian`` / ``stable`` on the curve's points against central differences of the averaged field
    ``I' = -D/Omega_d - (f1/2) sin psi``, ``psi' = Omega_d - Omega - (1/2)(df1/dI) cos psi`` in ``(I, psi)``
    (d/dI = (d/drho) / I'(rho); steps 1e-6 relative): the truncation error is ~1e-12, the round-off
    ``eps |f| / (h |df/drho| rho)`` ~ 2e-16 / (1e-6 * 1e-3) = 2e-7 of a row's largest entry (``psi'`` is a difference
    of terms ~omega that moves by ~1e-3 omega per unit of relative rho): 1e-5 of it leaves a margin of 50. The flags
    from the differenced matrix, away from the folds (det within 1e-6 of its two products' size of zero)."""
    _, av, _, _, rho, c, _ = curve
    psi = np.arctan2(av.sin_psi(rho), -c)
    Omega = av.omega_of(rho, c)

    def field(r, p):
        return (-av.D(r) / av.Od(r) - 0.5 * av.f1(r) * np.sin(p),
                av.Od(r) - Omega - 0.5 * av.df1(r) / av.dI(r) * np.cos(p))

    hr, hp = 1e-6 * rho, 1e-6
    dr = [(a - b) / (2 * hr) / av.dI(rho) for a, b in zip(field(rho + hr, psi), field(rho - hr, psi))]
    dp = [(a - b) / (2 * hp) for a, b in zip(field(rho, psi + hp), field(rho, psi - hp))]
    J = np.stack([np.stack([dr[0], dp[0]], -1), np.stack([dr[1], dp[1]], -1)], -2)
    got = av.jacobian(rho, c)
    row = np.abs(J).max(axis=2, keepdims=True)  # each row's scale (the rows differ by orders of magnitude)
    assert np.all(np.abs(got - J) <= 1e-5 * row)  # measured: 6e-7
    det = np.linalg.det(J)
    clear = np.abs(det) > 1e-6 * (np.abs(J[:, 0, 0] * J[:, 1, 1]) + np.abs(J[:, 0, 1] * J[:, 1, 0]))
    want = (np.trace(J, axis1=1, axis2=2) < 0) & (det > 0)
    assert clear.sum() >= 70 and want[clear].any() and not want[clear].all()
    np.testing.assert_array_equal(av.stable(rho, c)[clear], want[clear])
