"""STEP through tangent stiffnesses equals STEP through forces (exact cubic), and is refused where absent."""
import json

import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.runtime.counters import Counters
from stepnf.step.procedure import ForceEvaluator, StepPolicy, targeted_steps, targeted_steps_tangent
from stepnf_polynomial import PolynomialAdapter, save_system
from helpers.systems import random_system


def test_tangent_route_equals_force_route():
    M, K, G, H = random_system(8, seed=4)
    ad = PolynomialAdapter(M, K, G, H)
    Phi = np.linalg.eigh(K)[1][:, :2]  # any fields will do for G(phi, phi) and phi.H(phi, phi, phi)
    q = np.array([0.3, 0.2])
    c = Counters()
    a = targeted_steps(ForceEvaluator(ad.internal_forces, 8, c), ad.stiffness_matrix(), Phi, q, StepPolicy())
    b = targeted_steps_tangent(ad.tangent_stiffness, ad.stiffness_matrix(), Phi, q, StepPolicy(), counters=c)
    for x, y in zip(a, b):
        assert np.allclose(x.Gv, y.Gv, rtol=1e-12, atol=1e-13 * np.abs(x.Gv).max())  # both exact: round-off only
        assert y.h == pytest.approx(x.h, rel=1e-11)
    assert c.tangent_evaluations == 8  # 2 per mode, 2 more for the check amplitude


def test_scene_method_tangent(tmp_path, capsys):
    M, K, G, H = random_system(6, seed=2)
    save_system(tmp_path / "s.npz", M, K, G, H)
    p = tmp_path / "s.toml"
    p.write_text('[model]\nsolver = "polynomial"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0]\n'
                 'methods = ["dnf"]\n[analysis.step]\nmethod = "tangent"\n[output]\ndir = "o"\n')
    assert main(["run", str(p), "--json", "-q"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["counts"]["force_evaluations"] == 0 and doc["counts"]["tangent_evaluations"] == 4
    p.write_text(p.read_text().replace('method = "tangent"', 'method = "secant"'))
    assert main(["run", str(p), "-q"]) == 2
    assert "analysis.step.method" in capsys.readouterr().err


def test_tangent_h_is_bit_for_bit_the_old_expression():
    """h of the tangent route is ``float(phi @ ((K_T(+a) + K_T(-a) - 2K) @ phi)) / (6 a^2)`` to the last bit, as
    before H(phi, phi, phi) was kept (issue 29): scaling the vector first moved the last bits, hence the
    CalculiX method="tangent" results. Exact equality: the same operations in the same order."""
    from stepnf.plugin.adapter import checked_matrix

    M, K, G, H = random_system(12, seed=7)
    ad = PolynomialAdapter(M, K, G, H)
    K0 = ad.stiffness_matrix()
    Phi = np.linalg.eigh(K)[1][:, :4]
    q = np.array([0.3, 0.17, 0.011, 2.3])
    policy = StepPolicy()
    got = targeted_steps_tangent(ad.tangent_stiffness, K0, Phi, q, policy)
    differs = 0
    for j, res in enumerate(got):
        phi = Phi[:, j]
        for a, h, Hv in ((q[j], res.h, res.Hv), (policy.check_ratio * q[j], res.h_check, res.Hv_check)):
            Kp, Km = (checked_matrix(ad.tangent_stiffness(s * phi), "K_T", ad, 12) for s in (a, -a))
            X = (Kp + Km - 2.0 * K0) @ phi
            old = float(phi @ X) / (6.0 * a * a)
            assert h == old  # bit for bit
            assert np.array_equal(Hv, np.asarray(X).ravel() / (6.0 * a * a))  # H(phi, phi, phi) kept as well
            differs += float(phi @ (X / (6.0 * a * a))) != old  # the expression of the reviewed change
    assert differs  # the case tells the two expressions apart (else the test could not fail)
