"""Models given in modal coordinates run through the same pipeline and JSON schema."""
import json

import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.plugin.modal_model import ModalModel
from stepnf.plugin.shell_scales import ShellScales
from helpers.systems import use_solver  # noqa: E402


class Duffing2(ModalModel):
    """Two modes, x1'' + w1^2 x1 + g x1^2 + h x1^3 with g^2_11 = c coupling to mode 2."""

    def __init__(self, w1=1.0, w2=3.0, g11=0.4, g2=0.7, h=0.5):
        self.w = np.array([w1, w2])
        self.g = {0: np.array([g11, g2])}
        self.h = h

    def omegas(self):
        return self.w

    def labels(self):
        return [(0, 1), (1, 1)]

    def quadratic_coefficients(self, p):
        return self.g[p]

    def cubic_coefficient(self, p):
        return self.h

    def mode_maxima(self):
        return np.array([2.0, 2.0])

    def shell_scales(self):
        return ShellScales(kappa=4.0, omega_factor=1.0, thickness=1.0)


def test_modal_model_json(tmp_path, capsys, monkeypatch):
    use_solver(monkeypatch, lambda name: Duffing2)
    scene = tmp_path / "s.toml"
    scene.write_text('[model]\nsolver = "duffing"\nw2 = 3.0\n[analysis]\nmaster_modes = ["(0,1)"]\n'
                     'methods = ["nf", "dnf", "md", "smd"]\n[output]\ndir = "o"\n')
    assert main(["run", str(scene), "--json", "-q"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["kappa"] == 4.0
    (m,) = doc["modes"]
    assert m["label"] == [0, 1] and m["index"] == 0 and m["rho"] == pytest.approx(3.0)
    # closed-form NF with both modes (docs/design.md table, corrected denominators)
    w, ws, g1, g2, h = 1.0, 3.0, 0.4, 0.7, 0.5
    C4 = h - 2 * g1**2 * (w**2 - 2 * w**2) / (w**2 * (w**2 - 4 * w**2)) \
        - 2 * g2**2 * (ws**2 - 2 * w**2) / (ws**2 * (ws**2 - 4 * w**2))
    C5 = 4 * g1**2 * w**2 / (w**2 * (w**2 - 4 * w**2)) + 4 * g2**2 * w**2 / (ws**2 * (ws**2 - 4 * w**2))
    T = (3 * C4 + C5) / (8 * w**2)
    assert m["methods"]["nf"]["T"] == pytest.approx(T, rel=1e-14)
    assert m["methods"]["dnf"]["T"] == pytest.approx(T, rel=1e-14)  # all modes of the model
    assert m["methods"]["nf"]["gamma"] == pytest.approx(T / 4.0, rel=1e-14)  # Gamma = T / max|phi|^2
    assert doc["counts"]["force_evaluations"] == 0
