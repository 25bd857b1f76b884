"""Fig. 4 with the paper's DKT shell model (issue 32, item 5): the DKT sweep store of the Table 2 cases
(``docs/fig4/table2_dkt.h5``, ``examples/table2_dkt.toml``) beside the 3D solid's, one series per
thickness, and the DKT and 3D numbers the tests and the docs quote."""
from __future__ import annotations

import json

import pytest

from helpers.paths import REPO

from stepnf.report.fig4 import Point, fe_points, figure4, series

FIG4 = REPO / "docs" / "fig4"
STORE_3D, STORE_DKT = FIG4 / "table2.h5", FIG4 / "table2_dkt.h5"
CASES = {f"R={R:g}_h={h:g}" for R in (3.5, 2.5, 1.5, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3) for h in (0.001, 0.003, 0.005)}
MODES = {(2, 0), (3, 0), (4, 0), (0, 1), (0, 2), (2, 1)}


def test_dkt_store_holds_the_table2_cases_of_the_3d_store():
    dkt, solid = fe_points(STORE_DKT, "DKT"), fe_points(STORE_3D, "3D")
    for pts in (dkt, solid):
        assert {p.case for p in pts} == CASES and {p.mode for p in pts} == MODES and len(pts) == 180
    by_case = {(p.case, p.mode): p for p in solid}
    for p in dkt:  # same kappa, same thickness (read from the stored model geometry) as the 3D point
        q = by_case[(p.case, p.mode)]
        assert p.kappa == pytest.approx(q.kappa, rel=1e-12) and p.h == q.h and p.h in (0.001, 0.003, 0.005)


def test_dkt_against_3d_at_kappa25_stored():
    """The stored DKT points at kappa = 25 (h = 3 and 5 mm) against the 3D points: the issue's bound (5%, or
    0.005 absolute for the small (2,0)); h = 1 mm is no Table 2 case: tests/solvers/kratos/test_kratos_cap.py
    runs it. Also pins the 3D numbers test_kratos_cap.py quotes (its SOLID_3D), to the store's 7 digits."""
    solid = {(p.case, p.mode): p.gamma_fe for p in fe_points(STORE_3D)}
    dkt = {(p.case, p.mode): p.gamma_fe for p in fe_points(STORE_DKT)}
    quoted = {("R=1.5_h=0.003", (2, 0)): 0.0139951, ("R=1.5_h=0.003", (0, 1)): -0.2315230,
              ("R=1.5_h=0.003", (3, 0)): 0.1747630, ("R=0.9_h=0.005", (2, 0)): 0.0130494,
              ("R=0.9_h=0.005", (0, 1)): -0.2309941, ("R=0.9_h=0.005", (3, 0)): 0.1765922}
    for key, g in quoted.items():
        assert solid[key] == pytest.approx(g, abs=1e-7)
        if key[1] == (2, 0):
            assert dkt[key] == pytest.approx(g, abs=0.005), key
        else:
            assert dkt[key] == pytest.approx(g, rel=0.05), key
    bench = json.loads((REPO / "bench" / "results" / "shell_dkt.json").read_text())
    h1 = bench["runs"]["3d R=4.5_h=0.001 17.6k"]
    assert h1["kappa"] == pytest.approx(25.0) and h1["n_dofs"] == 17649
    for mode, g in {"(2,0)": 0.0144593, "(0,1)": -0.2315525, "(3,0)": 0.1732561}.items():
        assert h1["gamma"][mode] == pytest.approx(g, abs=1e-7)


def test_series_one_per_thickness():
    pts = [Point("s", f"c{i}", 25.0, (2, 0), 0.1, h=h) for i, h in enumerate((0.003, 0.001, 0.003))]
    pts.append(Point("s", "r", 30.0, (2, 0), 0.2, h=0.005, flags_fe=["internal_resonance_1_2"]))
    got = series("DKT", 1, pts, [0.001, 0.003, 0.005], [0.001, 0.003, 0.005])
    assert [(lab, c, len(p)) for lab, c, p in got] == [("DKT, h = 0.001", "C0", 1), ("DKT, h = 0.003", "C1", 2),
                                                       ("DKT, h = 0.005", "C2", 0)]  # the resonant point: grey
    assert [(lab, c) for lab, c, _ in series("vk", 0, pts[:1], [], [])] == [("vk, DNF", "C0")]


def test_figure4_draws_the_dkt_series(tmp_path):
    out = figure4([STORE_3D, STORE_DKT], tmp_path, names=["3D solid hex27", "DKT shell"], n_kappa=12)
    for name in ("3D solid hex27", "DKT shell"):
        assert {f"{name}, h = {h:g}" for h in (0.001, 0.003, 0.005)} <= set(out["series"])
    assert out["points"] == 360 and (tmp_path / "fig4.png").stat().st_size > 10_000
    rows = json.loads((tmp_path / "fig4_summary.json").read_text())["points"]
    assert sum(r["store"] == "DKT shell" for r in rows) == 180


def test_docs_fig4_has_the_dkt_points():
    """The figure in the docs was drawn with the DKT store: its table of points holds every DKT case."""
    rows = json.loads((FIG4 / "fig4_summary.json").read_text())["points"]
    dkt = [r for r in rows if r["store"].startswith("DKT")]
    assert {r["case"] for r in dkt} == CASES and len(dkt) == 180 and all(r["h"] for r in dkt)
