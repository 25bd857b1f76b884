"""The machine has what ``scripts/setup.sh tests`` installs, so that no solver's tests are skipped by accident.

On a fresh Debian 12 machine whose package lists held only the security updates, setup.sh once
left CalculiX out (it asked the stale lists whether Debian packages ``calculix-ccx``): every
CalculiX test was then skipped and the suite passed without running the solver. Debian 12 packages
it, so there a missing ``ccx`` is a failure of the set-up, not a reason to skip.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest


def _debian_version_id() -> str | None:
    try:
        text = Path("/etc/os-release").read_text()
    except OSError:
        return None
    fields = dict(line.split("=", 1) for line in text.splitlines() if "=" in line)
    if fields.get("ID", "").strip('"') != "debian":
        return None
    return fields.get("VERSION_ID", "").strip('"') or None


def test_calculix_is_installed_on_debian_12():
    if _debian_version_id() != "12":
        pytest.skip("Debian 12 only (Debian 13 packages no CalculiX; elsewhere ccx is the user's)")
    assert shutil.which("ccx") is not None, (
        "ccx is not on PATH on Debian 12: scripts/setup.sh tests should have installed calculix-ccx "
        "(the CalculiX tests would all be skipped)")
