"""Scenes that name programs, and the "program" they name: a shell script that leaves a marker file."""
from __future__ import annotations

import stat
from pathlib import Path

EVIL = '#!/bin/sh\ntouch "$(dirname "$0")/MARKER"\necho "evil ran: $*"\nexit 7\n'
MATERIAL = "[model.material]\nE = 2.0e11\nnu = 0.3\nrho = 7800.0\n"
ANALYSIS = '[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\nretained_modes = 4\n[output]\ndir = "out"\nplot = false\n'
CAP = '[model.geometry]\nshape = "spherical_cap"\na = 0.15\nR = 1.5\nh = 0.003\nn_core = 2\nn_ring = 1\n'


def script(path: Path, text: str = EVIL) -> Path:
    """An executable script at ``path`` (its folder made): by default one that leaves MARKER beside itself, exit 7."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return path


def code_aster_scene(folder: Path, extra: str) -> Path:
    """A code_aster scene on a generated cap in ``folder`` with the ``extra`` [model] keys, ``./evil.sh`` beside it."""
    folder.mkdir(parents=True, exist_ok=True)
    script(folder / "evil.sh")
    s = folder / "s.toml"
    s.write_text('[model]\nsolver = "code_aster"\n' + extra + CAP + MATERIAL + ANALYSIS)
    return s
