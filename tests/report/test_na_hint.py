"""Issue 31, item 8: an n/a caused by the STEP accuracy check says what to try ([analysis.step]
relative_amplitude, method = "tangent"); other n/a reasons and usable rows print no such hint."""
from __future__ import annotations

from stepnf.flags import STEP_UNUSABLE, t_unusable
from stepnf.io.results import ModeResult, RunResult
from stepnf.nf.coefficient import MethodResult
from stepnf.report.table import format_table


def table(*results: MethodResult) -> str:
    modes = [ModeResult(index=i, label=None, omega=1.0 + i, rho=None, methods={r.method: r})
             for i, r in enumerate(results)]
    return format_table(RunResult(scene={}, modes=modes, counts={}, timings={}, spectrum={}))


def hint_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("hint:")]


def test_step_accuracy_na_names_relative_amplitude():
    # T changes by 3x its size between the two amplitudes (>= STEP_UNUSABLE = 100%): the sign is not established
    r = MethodResult("dnf", -0.25, (0.0,) * 6, T_error=3 * STEP_UNUSABLE)
    assert t_unusable(r)[0] == "step_accuracy"
    text = table(r, MethodResult("dnf", 0.5, (0.0,) * 6, T_error=2 * STEP_UNUSABLE))
    hints = hint_lines(text)
    assert len(hints) == 1, text  # once per kind of n/a, not once per row
    assert "[analysis.step] relative_amplitude" in hints[0] and 'method = "tangent"' in hints[0]
    assert text.index("n/a [0 dnf]") < text.index(hints[0])  # under the n/a lines


def test_no_hint_for_usable_rows_or_other_reasons():
    usable = MethodResult("dnf", 0.25, (0.0,) * 6, T_error=1e-6)
    truncated = MethodResult("nf", 0.25, (0.0,) * 6, retained_modes=3, extra={"captured_fraction": 0.1})
    assert t_unusable(truncated)[0] == "modal_truncation"
    text = table(usable, truncated)
    assert "n/a [1 nf]" in text and "relative_amplitude" not in text and not hint_lines(text)
