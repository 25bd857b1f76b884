"""Fake solver plugins for tests that run stepnf in another process: a module and its entry point on a site folder."""
from __future__ import annotations

import os
from pathlib import Path


def fake_plugin(site: Path, module: str, source: str, entry: str) -> dict[str, str]:
    """Write ``module.py`` (``source``) and a ``module-0.1.dist-info`` registering ``entry`` (``"name = module:Class"``)
    in the group ``stepnf.solvers`` under ``site``; return the environment (``os.environ`` with ``site`` first on
    PYTHONPATH) in which a subprocess finds it."""
    info = site / f"{module}-0.1.dist-info"
    info.mkdir(parents=True)
    (site / f"{module}.py").write_text(source)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {module}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[stepnf.solvers]\n{entry}\n")
    return {**os.environ, "PYTHONPATH": str(site) + os.pathsep + os.environ.get("PYTHONPATH", "")}
