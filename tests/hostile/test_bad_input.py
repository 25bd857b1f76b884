"""Bad input and failing solvers: clear errors, non-zero exit codes, stored results intact."""
import json

import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.errors import StoreError
from stepnf.io.results import read_hdf5
from stepnf_polynomial import PolynomialAdapter, save_system
from helpers.systems import random_system, use_solver


class NaNForces(PolynomialAdapter):
    """A solver that returns NaN for its third field (a diverged Newton loop, say)."""

    def _internal_forces(self, U):
        F = super()._internal_forces(U)
        if len(F) > 2:
            F[2, 0] = np.nan
        return F


def scene(tmp_path, solver="polynomial"):
    M, K, G, H = random_system(6, seed=8)
    save_system(tmp_path / "s.npz", M, K, G, H)
    p = tmp_path / "s.toml"
    p.write_text(f'[model]\nsolver = "{solver}"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0]\n'
                 'methods = ["nf", "dnf"]\n[output]\ndir = "out"\n')
    return p


def test_nan_forces_fail_clearly_and_keep_previous_results(tmp_path, capsys, monkeypatch):
    s = scene(tmp_path)
    assert main(["run", str(s), "-q"]) == 0
    h5 = tmp_path / "out" / "s.h5"
    before = h5.read_bytes()
    use_solver(monkeypatch, lambda name: NaNForces)
    assert main(["run", str(s), "-q"]) == 3
    err = capsys.readouterr().err
    assert "NaN or inf internal forces for field(s) [2]" in err and "NaNForces" in err
    assert h5.read_bytes() == before  # the earlier run's file is untouched


def test_truncated_results_file(tmp_path):
    s = scene(tmp_path)
    assert main(["run", str(s), "-q"]) == 0
    h5 = tmp_path / "out" / "s.h5"
    data = h5.read_bytes()
    h5.write_bytes(data[: len(data) // 3])
    with pytest.raises(StoreError, match="corrupt or truncated"):
        read_hdf5(h5)


def test_foreign_hdf5_file(tmp_path):
    import h5py

    with h5py.File(tmp_path / "x.h5", "w") as f:
        f["a"] = 1
    with pytest.raises(StoreError, match="not a stepnf run file"):
        read_hdf5(tmp_path / "x.h5")


def test_no_nan_ever_reaches_the_json(tmp_path, capsys):
    """An exact 1:2 resonance gives '-inf' strings and flags, not NaN (json.loads would accept NaN)."""
    omega = np.array([1.0, 2.0])
    M = np.eye(2)
    K = np.diag(omega**2)
    G = np.zeros((2, 2, 2))
    G[1, 0, 0] = G[0, 0, 1] = G[0, 1, 0] = 0.3
    H = np.zeros((2,) * 4)
    save_system(tmp_path / "r.npz", M, K, G, H)
    p = tmp_path / "r.toml"
    p.write_text('[model]\nsolver = "polynomial"\nfile = "r.npz"\n[analysis]\nmaster_modes = [0]\n'
                 'methods = ["nf", "dnf", "md", "smd"]\n[output]\ndir = "o"\n')
    assert main(["run", str(p), "--json", "-q"]) == 0
    out = capsys.readouterr().out
    doc = json.loads(out, parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
    nf = doc["modes"][0]["methods"]["nf"]
    assert nf["T"] in ("-inf", "inf") and nf["flags"][0]["kind"] == "internal_resonance_1_2"
    assert nf["flags"][0]["mode"] == 1
