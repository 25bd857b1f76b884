"""The lines the table prints for a master on a manifold of several modes (stepnf.report.backbone_table,
issue 33): a coupled branch is traced past its validity limit (orders N-2 and N), so its line must say where
that limit is, not present the whole traced range as the backbone.

Block: the shape of stepnf.dpim.manifold_report's, with the numbers of the exact 1:2 system of
tests/pipeline/test_manifold_stage.py (order 7: a coupled branch traced to A = 1.565, Omega down to -0.0198,
valid to A = 0.9238 only).
"""
from __future__ import annotations

from stepnf.report.backbone_table import manifold_lines


def _branch(valid, reason):
    return {"kind": "coupled", "masters": [0, 1], "ratios": [1, 2], "Omega": [0.999114, 0.7, -0.019814],
            "A": [[0.004999, 0.9, 1.565], [1e-5, 0.3, 0.6]], "stable": [True, True, True],
            "valid_up_to": valid, "valid_reason": reason}


def _block(*branches):
    return {"manifold": {"modes": [0, 1], "ratios": [1, 2], "chosen": "explicit", "why": "manifolds[0]",
                         "resonant_monomials": 44}, "coupled_branches": list(branches)}


def test_coupled_branch_line_says_its_validity():
    lines = manifold_lines(_block(_branch(0.9238485760957179, "orders differ"), _branch(None, "not reached"),
                                  _branch(None, "no lower order")), 0)
    assert "valid up to A = 0.9238 (orders differ); traced beyond" in lines[1]
    assert "orders agree over the range traced" in lines[2]
    assert "no validity range (no lower order)" in lines[3]


def test_figure_fades_a_coupled_branch_beyond_its_validity():
    """The branches figure (stepnf.report.branches_plot): the coupled branch above, valid to A = 0.9238, is
    faded past it (dashed stays for unstable orbits), not drawn as the trusted part is."""
    from types import SimpleNamespace

    from stepnf.report.branches_plot import FADED, draw_branches
    from stepnf.report.figures import pyplot

    block = dict(_block(_branch(0.9238485760957179, "orders differ")), branch=None, valid_up_to=0.0)
    fig, ax = pyplot().subplots()
    draw_branches(ax, SimpleNamespace(index=0, label=None, omega=1.0, backbone=block))
    alphas = {(line.get_label(), line.get_alpha()) for line in ax.get_lines()}
    pyplot().close(fig)
    assert ("coupled 1", 1.0) in alphas and ("coupled 1, beyond validity", FADED) in alphas
