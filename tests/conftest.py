"""Shared pytest set-up: tests/ on sys.path, and no test skipped for want of a tool the set-up installs.

The tools ``bash scripts/setup.sh tests`` installs on this Debian release (``tests/required_tools.txt``,
see ``tests/helpers/required.py``) are listed in the header of every run. A test marked ``requires(...)``
fails when one of them is missing (skips where the release does not promise it, as ccx on Debian 13),
and any other skip whose reason names a required tool that is missing (``importorskip``, an inline
``pytest.skip``) is turned into a failure at run time (issue 29). A module skipped at collection for a
missing required tool stays skipped, so that the other modules still run (a failed collection stops pytest:
"Interrupted: 1 error during collection"), and the run fails at its end with a line naming the module and
the tool.
"""
import os
import sys
from pathlib import Path

import pytest

# tests/helpers (from helpers.systems import ...)
sys.path.insert(0, str(Path(__file__).parent))

from helpers import required  # noqa: E402


def pytest_configure(config):
    config.addinivalue_line("markers", "requires(*tools): needs these tools of tests/required_tools.txt "
                            "(missing: a failure where the set-up installs them, else a skip)")


def pytest_report_header(config):
    release = required.debian_release()
    if not required.required():
        return [f"required tools: none on this system (Debian release {release}; tests/required_tools.txt)"]
    names = ", ".join(required.required())
    missing = ", ".join(t.name for t in required.missing_required()) or "none"
    return [f"required tools (Debian {release}, installed by `bash scripts/setup.sh tests`; "
            f"their tests fail, not skip, without them): {names}; missing: {missing}"]


def pytest_runtest_setup(item):
    for mark in item.iter_markers("requires"):
        required.need(*mark.args)


def _skip_reason(report) -> str:
    longrepr = report.longrepr
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        return str(longrepr[2])
    return str(longrepr)


def _fail_promised_skip(report) -> None:
    """A skip whose reason names a required tool that is missing becomes a failure naming it."""
    if not report.skipped or hasattr(report, "wasxfail"):
        return
    reason = _skip_reason(report)
    tools = required.promised_in(reason)
    if tools:
        report.outcome = "failed"
        report.longrepr = "; ".join(required.message(t) for t in tools) + f" (the test's skip said: {reason})"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    _fail_promised_skip(outcome.get_result())


#: Per run: "module: message" for every module skipped at collection for a missing required tool.
PROMISED_MODULES = pytest.StashKey[list]()


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    report = outcome.get_result()
    if report.skipped:
        tools = required.promised_in(_skip_reason(report))
        if tools:
            collector.config.stash.setdefault(PROMISED_MODULES, []).append(
                f"{report.nodeid}: " + "; ".join(required.message(t) for t in tools)
                + f" (the module's skip said: {_skip_reason(report)})")


def pytest_sessionfinish(session, exitstatus):
    """A module skipped for a missing required tool fails the run (its tests did not run)."""
    if session.config.stash.get(PROMISED_MODULES, None) and exitstatus in (
            pytest.ExitCode.OK, pytest.ExitCode.NO_TESTS_COLLECTED):
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    for line in config.stash.get(PROMISED_MODULES, []):
        terminalreporter.write_line(f"FAILED (module not run) {line}", red=True)


@pytest.fixture
def umask000():
    """The process's umask 000 during the test (what a careless shell profile sets): folders that must be private
    are checked to be created 0700 all the same."""
    old = os.umask(0)
    yield
    os.umask(old)
