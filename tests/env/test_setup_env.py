"""The machine has what ``scripts/setup.sh tests`` installs, and no solver's test is skipped for want of it.

On a fresh Debian 12 machine setup.sh once dropped CalculiX (``apt-cache policy calculix-ccx | grep -q``
under ``pipefail`` returned 141 when grep closed the pipe: issue 29): every CalculiX test was then
skipped and the suite passed without running the solver. ``tests/required_tools.txt`` lists what the
set-up installs on each Debian release; ``tests/conftest.py`` fails, not skips, a test that needs a
listed tool that is missing. Here: every listed tool is there, setup.sh asks for every listed package,
and a run with ccx taken away on purpose fails (on Debian 12; it skips on Debian 13, which has no ccx).
"""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from helpers import required
from helpers.paths import REPO, TESTS

ROOT = REPO
RELEASE = required.debian_release()
PROBE = textwrap.dedent('''
    import shutil
    import pytest
    from helpers.required import requires

    @requires("ccx")
    def test_marked():
        assert shutil.which("ccx") is not None

    @pytest.mark.skipif(shutil.which("ccx") is None, reason="ccx (Debian calculix-ccx) not installed")
    def test_old_marker():
        pass

    def test_inline_skip():
        pytest.skip("CalculiX (ccx) not installed")

    def test_genuine_skip():
        pytest.skip("needs two MPI ranks")
''')


@pytest.mark.parametrize("name", sorted(required.required()) or [pytest.param("-", marks=pytest.mark.skip(
    reason=f"no tools required on this system (Debian release {RELEASE}): tests/required_tools.txt"))])
def test_required_tool_is_installed(name):
    tool = required.required()[name]
    assert tool.present(), required.message(tool)


def test_setup_asks_for_every_required_package():
    """The packages of tests/required_tools.txt, for either Debian release, are among setup.sh's."""
    if RELEASE not in ("12", "13"):
        pytest.skip(f"scripts/setup.sh supports Debian 12 and 13, this is {RELEASE or 'not Debian'}")
    done = subprocess.run(["bash", "scripts/setup.sh", "tests"], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "STEPNF_SETUP_DRY_RUN": "1"}, stdin=subprocess.DEVNULL, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    line = next(ln for ln in done.stdout.splitlines() if ln.startswith("setup: Debian packages asked for:"))
    asked = set(line.split(":", 1)[1].split())
    for tool in required.required().values():
        if tool.package.startswith("editable:"):
            assert (ROOT / tool.package.split(":", 1)[1] / "pyproject.toml").is_file(), tool
        else:
            assert tool.package in asked, (tool, sorted(asked))
    assert done.stdout.rstrip().endswith("nothing installed"), done.stdout


def os_release(tmp_path: Path, version: str) -> Path:
    path = tmp_path / f"os-release-{version}"
    path.write_text(f'PRETTY_NAME="Debian GNU/Linux {version}"\nNAME="Debian GNU/Linux"\nVERSION_ID="{version}"\n'
                    'ID=debian\n')
    return path


def pytest_without_ccx(args: list[str], cwd: Path, release: Path) -> subprocess.CompletedProcess:
    """``python -m pytest ARGS`` with no ccx on PATH (PATH is an empty folder beside ``release``, in the test's
    temporary folder: never in the checkout), as on Debian ``release``."""
    empty = release.parent / "empty-path"
    empty.mkdir(exist_ok=True)
    env = {**os.environ, "PATH": str(empty), "STEPNF_TEST_OS_RELEASE": str(release),
           "PYTHONPATH": str(TESTS)}
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", *args], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize("version", ["12", "13"])
def test_a_missing_ccx_fails_the_suite_on_debian_12_and_skips_on_13(tmp_path, version):
    """ccx taken away on purpose: the marked test, an old skipif and an inline skip naming ccx fail on
    Debian 12 (its set-up installs ccx) and skip on Debian 13; a skip for another reason stays a skip."""
    (tmp_path / "test_probe.py").write_text(PROBE)
    (tmp_path / "pytest.ini").write_text("[pytest]\n")  # this folder is the root: only tests/conftest.py's hooks
    done = pytest_without_ccx(["-p", "conftest", "test_probe.py"], tmp_path, os_release(tmp_path, version))
    out = done.stdout
    if version == "12":
        assert done.returncode == 1, out + done.stderr
        # the mark and the skipif act before the test (errors at set-up), the inline skip within it (a failure)
        assert out.rstrip().splitlines()[-1].startswith("1 failed, 1 skipped, 2 errors"), out
        assert out.count("ccx is missing, and on Debian 12 `bash scripts/setup.sh tests` installs it") >= 3, out
        assert "SKIPPED [1] test_probe.py" in out and "needs two MPI ranks" in out, out
    else:
        assert done.returncode == 0, out + done.stderr
        assert "4 skipped" in out and "ccx is missing" not in out, out


def test_a_calculix_test_fails_without_ccx_on_debian_12(tmp_path):
    """One real CalculiX test file, ccx taken off PATH: the run fails and names ccx (it does not skip)."""
    done = pytest_without_ccx([str(TESTS / "solvers" / "calculix" / "test_calculix.py"), "-k", "affine_patch",
                               "--rootdir", str(ROOT), "--basetemp", str(tmp_path / "t")], ROOT,
                              os_release(tmp_path, "12"))
    assert done.returncode == 1, done.stdout + done.stderr
    assert "ccx is missing, and on Debian 12" in done.stdout, done.stdout
    assert "1 error" in done.stdout and " skipped" not in done.stdout, done.stdout


@pytest.mark.parametrize("version", ["12", "13"])
def test_a_module_skipped_for_a_missing_ccx_fails_the_run_on_debian_12_and_the_rest_runs(tmp_path, version):
    """``pytest.importorskip`` or a module-level skip naming a missing required tool fails the run, naming the
    tool, on Debian 12 (skips on 13); it does not stop the run (review item 9: a failed collection made pytest
    stop with "Interrupted: 1 error during collection" and no other test ran)."""
    (tmp_path / "test_probe_module.py").write_text(
        'import pytest\npytest.skip("ccx (Debian calculix-ccx) not installed", allow_module_level=True)\n\n'
        'def test_never():\n    pass\n')
    (tmp_path / "test_probe_other.py").write_text('def test_runs():\n    pass\n')
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    done = pytest_without_ccx(["-p", "conftest", "test_probe_module.py", "test_probe_other.py"], tmp_path,
                              os_release(tmp_path, version))
    out = done.stdout
    assert "Interrupted" not in out and "1 passed, 1 skipped" in out.rstrip().splitlines()[-1], out + done.stderr
    if version == "12":
        assert done.returncode == 1, out + done.stderr
        assert "test_probe_module.py: ccx is missing, and on Debian 12" in out, out
    else:
        assert done.returncode == 0 and "ccx is missing" not in out, out + done.stderr
