"""``stepnf verify``: the scene's DPIM backbones side by side with full-model periodic orbits.

* A polynomial scene (the 2-dof system of tests/helpers/systems.two_dof, quadratic and cubic terms): the
  CLI's numbers by shooting and by time integration agree with the backbone to 1e-5 at A = 0.8,
  where w_NL/w - 1 = 11%.
* Wrong inputs are exit 2 with a message naming what is wrong, a failed orbit exit 3 naming the
  mode and the amplitude, never a traceback.
* The issue's FE done-means (slow): the kappa = 25 cap, modes (2,0) and (0,1), two amplitudes each,
  backbone against full-model time integration to 1e-3.
"""
from __future__ import annotations

import json
import time

import pytest

from stepnf.verify import command as verify
from stepnf.cli.main import main
from helpers.meshes import cap_model_toml
from helpers.scenes import TWO_DOF_BACKBONE, run_verify, write_two_dof_scene


@pytest.mark.parametrize("method", ["shooting", "integration"])
def test_polynomial_scene_side_by_side(tmp_path, capsys, monkeypatch, method):
    """Backbone (order 21) and the full model's orbit at A = 0.5 (4% shift) and 0.8 (11%), to 1e-5.

    DPIM order 21 is within 1e-7 of the exact orbit at A = 0.8 (test_dpim); shooting is exact to
    ~1e-12 (test_periodic). Measured differences: shooting 7e-12 and 2.3e-7; integration (rtol 1e-6,
    from the parametrisation's point, 3 periods) 2e-9 and 1.7e-7, the latter from the quasi-periodic
    motion of a start 1e-3 off the true manifold (its distance, reported). Bound 1e-5, the issue's.
    """
    if method == "integration":
        monkeypatch.setattr(verify, "SHOOTING_LIMIT", 0)
    path = write_two_dof_scene(tmp_path)
    code, out, err = run_verify(capsys, path, "--amplitudes", 0.5, 0.8, "--json", "--quiet")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["method"] == method and doc["n_dofs"] == 2
    (mode,) = doc["modes"]
    assert mode["order"] == 21 and mode["amplitudes_from"] == "--amplitudes"
    checks = mode["checks"]
    assert [c["amplitude"] for c in checks] == [0.5, 0.8]
    assert checks[1]["omega_check_over_omega"] - 1 > 0.10  # the condition: w changes by >= 5%
    for c in checks:
        assert abs(c["relative_difference"]) < 1e-5, c
        assert c["omega_dpim"] / c["omega_check"] - 1 == pytest.approx(c["relative_difference"], abs=1e-15)
        assert c["orbit_amplitude"] == pytest.approx(c["amplitude"], rel=1e-5)
        assert 0 <= c["manifold_distance"] < 1e-2  # measured <= 1.1e-3 (A = 0.8, integration)
    # the table: one row per amplitude, both ratios printed
    code, out, _ = run_verify(capsys, path, "--amplitudes", 0.8, "--quiet")
    assert code == 0
    lines = out.splitlines()
    row = lines[next(i for i, line in enumerate(lines) if "w_DPIM/w" in line) + 1].split()
    assert float(row[0]) == pytest.approx(0.8, rel=1e-5)  # the amplitude measured on the orbit
    assert float(row[1]) == pytest.approx(checks[1]["omega_dpim_over_omega"], rel=1e-9)
    assert float(row[2]) == pytest.approx(checks[1]["omega_check_over_omega"], rel=1e-9)


def test_default_amplitudes_up_to_the_validity_limit(tmp_path, capsys):
    """Without --amplitudes: three amplitudes evenly up to the validity limit (orders 19 and 21 within
    1e-3 of each other there), each checked by shooting.

    Measured differences: 7e-15, 1.3e-7, 8.0e-4 at A = 0.39, 0.78, 1.17 (the limit): the order-21
    error at the limit is of the size of the tolerance that defines the limit (the series is near
    its radius of convergence there), so the last point is held to that tolerance, 1e-3.
    """
    code, out, err = run_verify(capsys, write_two_dof_scene(tmp_path), "--json")
    assert code == 0, err
    assert "master mode 0" in err  # progress on stderr
    (mode,) = json.loads(out)["modes"]
    assert mode["amplitudes_from"].startswith("validity limit")
    A = [c["amplitude"] for c in mode["checks"]]
    assert len(A) == 3 and A[1] == pytest.approx(2 * A[0]) and A[2] == pytest.approx(3 * A[0])
    diffs = [abs(c["relative_difference"]) for c in mode["checks"]]
    assert diffs[0] < 1e-5 and diffs[1] < 1e-5 and diffs[2] < 1e-3, diffs


@pytest.mark.parametrize("args,where", [
    ((), "[analysis.backbone]"),                                   # no backbone table
    (("--amplitudes", "-1"), "--amplitudes"),
    (("--amplitudes", "0"), "--amplitudes"),
    (("--periods", "0.5"), "--periods"),
    (("--periods", "nan"), "--periods"),
])
def test_wrong_inputs_exit_2(tmp_path, capsys, args, where):
    backbone = "" if not args else TWO_DOF_BACKBONE
    code, out, err = run_verify(capsys, write_two_dof_scene(tmp_path, backbone), *args, "--quiet")
    assert code == 2 and where in err and "Traceback" not in err and out == ""


def test_missing_scene_and_bad_numbers(tmp_path, capsys):
    code, _, err = run_verify(capsys, tmp_path / "nope.toml")
    assert code == 2 and "nope.toml" in err and "Traceback" not in err
    with pytest.raises(SystemExit) as exc:  # argparse: not a number
        main(["verify", str(write_two_dof_scene(tmp_path)), "--amplitudes", "abc"])
    assert exc.value.code == 2 and "invalid float value" in capsys.readouterr().err


def test_beyond_validity_exit_2_and_failed_orbit_exit_3(tmp_path, capsys, monkeypatch):
    """An amplitude beyond the validity limit is refused (exit 2, naming the mode and the limit); an orbit
    that fails (here: shooting's Newton, forced above A = 0.3) is listed with the mode and the amplitude
    beside the checks that worked, and the run exits 3."""
    path = write_two_dof_scene(tmp_path)
    code, _, err = run_verify(capsys, path, "--amplitudes", 0.5, 50, "--quiet")
    assert code == 2 and "master mode 0" in err and "validity limit" in err and "Traceback" not in err
    from stepnf.errors import NumericalError
    from stepnf.verify.periodic import Shooting

    works = Shooting.at_amplitude

    def fail_above(self, A, **kw):
        if A > 0.3:
            raise NumericalError("shooting: Newton did not converge in 25 iterations at q0 = 0.5")
        return works(self, A, **kw)
    monkeypatch.setattr(Shooting, "at_amplitude", fail_above)
    code, out, err = run_verify(capsys, path, "--amplitudes", 0.2, 0.5, "--quiet")
    assert code == 3 and "1 of 2 orbits could not be computed" in err and "Traceback" not in err
    rows = [line for line in out.splitlines() if line.startswith("  ") and "w_DPIM" not in line]
    assert len(rows) == 2 and "no orbit" not in rows[0]
    assert "no orbit: master mode 0" in rows[1] and "did not converge" in rows[1] and "0.5" in rows[1]


# ------------------------------------------------------------------------- FE (slow)
CAP_ANALYSIS = """
[analysis]
master_modes = ["(2,0)", "(0,1)"]
methods = ["dnf"]

[analysis.backbone]
order = 7
points = 4
"""


@pytest.mark.fenicsx
@pytest.mark.slow
def test_kappa25_cap_against_time_integration(tmp_path):
    """The issue's FE done-means: backbones of (2,0) and (0,1) against full-model time integration.

    The kappa = 25 cap of examples/shell_kappa25.toml on a coarser mesh (n_core = 8, n_ring = 3,
    ~5k dofs, instead of the default 18k: same verification, 1/4 of the time; see the report for the
    default mesh), DPIM order 7, at 1/4 and 1/2 of each backbone's validity limit (orders 5 and 7
    within 1e-3): W_max/h up to ~0.6. The integration (2 periods, dt and dt/2 with 40 and 80 steps a
    period, Richardson) is accurate to ~1e-5 (rtol); the DPIM truncation at half the validity limit
    to ~1e-4 (orders 5 and 7 differ by < 1e-3 up to the limit, and the difference falls like A^2).
    Bound 1e-3, the issue's. Measured (6057 dofs): (2,0) 1.7e-6 and -6.5e-7 at w_NL/w - 1 = 0.11% and
    0.43%; (0,1) 2.5e-6 and 2.9e-6 at -0.55% and -2.2%; 72 s alone (95 s beside another run). On the
    default 17649-dof mesh the same check gives 1.7e-6, -7.2e-7, 2.5e-6, 3.3e-6 in 304 s (too long here).
    """
    pytest.importorskip("dolfinx")
    from stepnf.scene.parse import load_scene

    path = tmp_path / "cap.toml"
    path.write_text(cap_model_toml(8, 3) + CAP_ANALYSIS)
    t0 = time.perf_counter()
    doc = verify.verify_scene(load_scene(path), periods=2, rtol=1e-5, fractions=(0.25, 0.5))
    seconds = time.perf_counter() - t0
    assert doc["method"] == "integration"
    labels = [tuple(m["label"]) for m in doc["modes"]]
    assert labels == [(2, 0), (0, 1)]
    shifts = {}
    for m in doc["modes"]:
        assert len(m["checks"]) == 2
        for c in m["checks"]:
            assert abs(c["relative_difference"]) < 1e-3, (m["label"], c)
        shifts[tuple(m["label"])] = m["checks"][-1]["omega_check_over_omega"] - 1
    assert shifts[(0, 1)] < -0.005  # softening, visibly (measured: see the report)
    print(verify.format_report(doc), f"\n{seconds:.1f} s")
