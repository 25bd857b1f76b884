"""The printed table marks the numbers the tool knows to be wrong as n/a (issue 13); JSON keeps them."""
import json
import math

from stepnf.nf.coefficient import MethodResult
from stepnf.io.results import ModeResult, RunResult
from stepnf.report.table import format_table
from stepnf.flags import STEP_UNUSABLE, TRUNCATION_UNUSABLE, t_unusable


def unusable_reason(r):
    """The table's phrase for an n/a T, or None."""
    verdict = t_unusable(r)
    return verdict[1] if verdict else None


def result(**kw):
    base = dict(method="nf", T=-1.25e3, C=(0.0,) * 6, retained_modes=20)
    base.update(kw)
    return MethodResult(**base)


def run_of(methods):
    mode = ModeResult(index=0, label=(2, 0), omega=100.0, rho=0.1, methods=methods)
    return RunResult(scene={"solver": "polynomial"}, modes=[mode], counts={}, timings={"total": 0.0},
                     spectrum={})


def test_heavily_truncated_modal_sum_is_unusable():
    r = result(extra={"captured_fraction": 1e-9})
    assert "20 retained modes carry 1e-07%" in unusable_reason(r)


def test_the_threshold_is_inclusive_of_usable_results():
    assert unusable_reason(result(extra={"captured_fraction": TRUNCATION_UNUSABLE})) is None
    assert unusable_reason(result(extra={"captured_fraction": 0.999})) is None
    assert unusable_reason(result(extra={"captured_fraction": math.nextafter(TRUNCATION_UNUSABLE, 0)}))


def test_fraction_read_from_the_flag_of_a_stored_result():
    r = result(flags=[{"kind": "modal_truncation", "value": 0.2, "message": "m"}])
    assert "20%" in unusable_reason(r)


def test_step_error_of_order_one_is_unusable():
    assert unusable_reason(result(method="dnf", T_error=0.5)) is None
    assert "not even its sign" in unusable_reason(result(method="dnf", T_error=STEP_UNUSABLE))
    assert unusable_reason(result(method="dnf", T_error=math.inf))


def test_table_shows_na_with_reason_and_json_keeps_the_number():
    bad = result(extra={"captured_fraction": 3e-9},
                 flags=[{"kind": "modal_truncation", "value": 3e-9, "message": "NF: the 20 retained modes"}])
    good = result(method="dnf", T=-2.5e-1, gamma=-0.0123)
    run = run_of({"dnf": good, "nf": bad})
    table = format_table(run)
    nf_line = next(line for line in table.splitlines() if line.split()[:1] == ["nf"])
    assert nf_line.split()[1:4] == ["n/a", "n/a", "n/a"], table
    dnf_line = next(line for line in table.splitlines() if "dnf" in line.split())
    assert "-2.5000e-01" in dnf_line and "softening" in dnf_line and "-0.0123" in dnf_line
    assert "n/a [0 nf]: the 20 retained modes carry 3e-07% of G(phi_p, phi_p)" in table
    assert "flag [0 nf]" not in table  # the truncation is said once, by the n/a line
    assert "-1.2500e+03" not in table
    doc = json.loads(run.to_json())
    assert doc["modes"][0]["methods"]["nf"]["T"] == -1.25e3
    assert doc["modes"][0]["methods"]["nf"]["behaviour"] == "softening"
