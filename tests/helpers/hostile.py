"""Shared checks of the hostile-input tests (``tests/hostile/``).

Every failure a user can cause must end as a message on stderr that names
where the problem is (file, key, line or stage) and an exit code: 2 for bad
input, 3 for a numerical or solver failure. Never a Python traceback, never
exit 1 (the CLI's "internal error" code, which means a bug in stepnf).
"""
from __future__ import annotations

import os
import subprocess
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import pytest

from stepnf.cli.main import main


@dataclass
class Outcome:
    code: int
    out: str
    err: str


def run_cli(args: Sequence[str], capsys) -> Outcome:
    """``stepnf ARGS`` in this process; an exception escaping ``main`` is a traceback the user would see."""
    capsys.readouterr()
    try:
        code = main([str(a) for a in args])
    except SystemExit as exc:  # argparse's own usage errors exit 2 without a traceback
        code = int(exc.code or 0)
    except BaseException:  # noqa: BLE001 - the point of the test
        pytest.fail("stepnf raised instead of reporting:\n" + traceback.format_exc())
    cap = capsys.readouterr()
    return Outcome(code, cap.out, cap.err)


def run_cli_process(args: Sequence[str], *, cwd: Path | None = None, env: dict | None = None,
                    timeout: float = 300) -> Outcome:
    """``stepnf ARGS`` in a fresh interpreter: catches crashes (segmentation faults) as well."""
    full_env = dict(os.environ)
    full_env.update(env or {})
    p = subprocess.run([sys.executable, "-m", "stepnf.cli.main", *map(str, args)], cwd=cwd, env=full_env,
                       capture_output=True, text=True, timeout=timeout)
    return Outcome(p.returncode, p.stdout, p.stderr)


def assert_reported(o: Outcome, codes: Iterable[int] = (2, 3), mentions: Iterable[str] = ()) -> None:
    """Exit code among ``codes``, no traceback, and stderr names every string in ``mentions``."""
    codes = tuple(codes)
    assert "Traceback" not in o.err, o.err
    assert o.code in codes, f"exit {o.code}, expected one of {codes}; stderr:\n{o.err}"
    for m in mentions:
        assert m in o.err, f"{m!r} not named in the message:\n{o.err}"


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes), to show earlier results are untouched."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}
