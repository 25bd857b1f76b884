"""Fig. 4: sweep points on the von Karman curves, the table of points and the per-mode differences."""
import json
from pathlib import Path

import pytest

from stepnf.cli.main import main
from stepnf.report.fig4 import fe_points, summary, vonkarman_at
from stepnf.sweep.dask_sweep import load_sweep, run_sweep


def vk_sweep(tmp_path: Path) -> Path:
    (tmp_path / "base.toml").write_text(
        '[model]\nsolver = "vonkarman"\nkappa = 0.0\n'
        '[analysis]\nmaster_modes = ["(2,0)", "(0,1)", "(2,1)"]\nmethods = ["dnf", "nf"]\n')
    s = tmp_path / "sw.toml"
    s.write_text('[sweep]\nname = "vk"\nbase = "base.toml"\n[sweep.vary]\n"model.kappa" = [0.0, 4.0, 25.0]\n'
                 '[sweep.dask]\nn_workers = 1\n[output]\ndir = "out"\n')
    run_sweep(load_sweep(s))
    return tmp_path / "out" / "vk.h5"


def test_fig4_of_the_model_against_itself(tmp_path, capsys):
    """A sweep of the von Karman model itself lands exactly on its curves: differences at round-off."""
    store = vk_sweep(tmp_path)
    pts = fe_points(store)
    assert len(pts) == 9 and {p.kappa for p in pts} == {0.0, 4.0, 25.0}
    vonkarman_at(pts)
    # Same model, two processes: the sweep ran in a Dask worker (one BLAS thread), the curves here (the
    # machine's default). Threaded BLAS sums in another order, so the model's eigen-solve and quadrature
    # sums differ at ~1e-15 relative; the NF denominators near the (2,0)-(0,1) 1:2 resonance (kappa ~ 3,
    # next to the kappa = 4 point) and the eigenvector sensitivity amplify that to the measured 3e-12
    # (8e-12 on another machine). rel = 1e-10 keeps a decade of margin and is still far below any
    # modelling difference Fig. 4 shows (>= 1e-4).
    rel = 1e-10
    for p in pts:
        assert p.gamma_vk == pytest.approx(p.gamma_fe, rel=rel, abs=1e-14)
    s = summary(pts)
    scale = max(abs(p.gamma_fe) for p in pts)
    assert all(v["max_abs_difference"] < rel * scale for v in s.values())
    assert main(["fig4", str(store), "--out", str(tmp_path / "fig"), "--n-kappa", "20"]) == 0
    out = capsys.readouterr().out
    assert "max |dGamma|" in out and (tmp_path / "fig" / "fig4.png").stat().st_size > 10_000
    rows = json.loads((tmp_path / "fig" / "fig4_summary.json").read_text())["points"]
    assert len(rows) == 9
    # the (2,0) point at kappa = 4 sits near the (2,0)-(0,1) 1:2 resonance (kappa ~ 3): flagged, left out
    near = [r for r in rows if r["mode"] == "(2,0)" and r["kappa"] == 4.0]
    assert near and near[0]["resonant"] == ("internal_resonance_1_2" in near[0]["flags_vk"])
