"""``[analysis.backbone] manifolds`` on a model in modal coordinates (the von Karman model): its backbones are
single-mode DPIMs (stepnf.pipeline.modal_coordinates), so the key must be refused in one line naming it (exit 2),
not ignored while the run prints single-mode backbones as if they were the manifold's (issue 33 review)."""
from __future__ import annotations

import pytest

from stepnf.cli.main import main


@pytest.mark.parametrize("keys", ['manifolds = [["(0,1)", "(0,2)"]]\n', 'manifolds = "auto"\nresonance = 0.02\n'])
def test_manifolds_refused_on_a_modal_model(tmp_path, capsys, keys):
    path = tmp_path / "vk.toml"
    path.write_text('[model]\nsolver = "vonkarman"\nedge = "clamped"\nkappa = 10.0\n[analysis]\n'
                    f'master_modes = ["(0,1)"]\nmethods = ["dnf"]\n[analysis.backbone]\norder = 5\n{keys}'
                    '[output]\ndir = "out"\n')
    assert main(["run", str(path), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "[analysis.backbone.manifolds]" in err and "vonkarman" in err
    assert "Traceback" not in err
