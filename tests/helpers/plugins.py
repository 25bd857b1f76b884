"""Fake solver plugins for tests that run stepnf in another process: a module and its entry point on a site folder."""
from __future__ import annotations

import os
import textwrap
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


#: a plugin module ``slowmodel`` whose solver ``slow`` is a two-mode modal model that may sleep (sweep tests)
SLOW_PLUGIN = textwrap.dedent('''
    import os
    import time
    import numpy as np
    from stepnf.plugin.modal_model import ModalModel
    from stepnf.plugin.shell_scales import ShellScales

    class Slow(ModalModel):
        """Two-mode model whose coupling grows with kappa; sleeps (SLOW_DELAY seconds: no scene key, which
        would make the resumed sweep's model another one) to make the sweep killable."""
        def __init__(self, kappa):
            if kappa == 3:
                raise ValueError("kappa = 3 is a case that fails on purpose")
            time.sleep(float(os.environ.get("SLOW_DELAY", "0")))
            self.kappa = float(kappa)
        def omegas(self):
            return np.array([1.0, 2.5 + self.kappa])
        def labels(self):
            return [(0, 1), (0, 2)]
        def quadratic_coefficients(self, p):
            return np.array([0.1, 0.3 * np.sqrt(self.kappa)])
        def cubic_coefficient(self, p):
            return 0.5
        def shell_scales(self):
            return ShellScales(kappa=self.kappa, omega_factor=1.0, thickness=1.0)
''')


def write_slow_sweep(tmp_path):
    """``base.toml`` and ``sweep.toml`` in ``tmp_path``: six kappa cases of the ``slow`` solver on two Dask
    workers (kappa = 3 fails on purpose); returns the sweep file."""
    (tmp_path / "base.toml").write_text(
        '[model]\nsolver = "slow"\nkappa = 1.0\n'
        '[analysis]\nmaster_modes = [0]\nmethods = ["nf", "md", "smd"]\n')
    sweep = tmp_path / "sweep.toml"
    sweep.write_text('[sweep]\nname = "demo"\nbase = "base.toml"\n'
                     '[sweep.vary]\n"model.kappa" = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]\n'
                     '[sweep.dask]\nn_workers = 2\n[output]\ndir = "out"\n')
    return sweep
