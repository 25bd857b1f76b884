"""(k, n) labels and held rims of a mid-surface model with six dofs per node (issue 32, item 1): the labels
read the node translations only, so a mode whose largest entries are rotations is labelled by its
displacement.

Reference: hand-built fields on a disc of nodes: w = r^2 cos(2 theta) is the (2, 0) shape, w = 1 - 2 r^2
the (0, 1) shape (one sign change of its radial profile); their rotations (the slopes of w, and a drilling
rz) are set 50 times larger than w in radians. Before this change no labeler took dof fields.
"""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.geometry.labels import ModeLabeler, edge_is_held

R_NODES = np.linspace(0.0, 1.0, 9)[1:]
T_NODES = np.linspace(0.0, 2 * np.pi, 32, endpoint=False)


def disc():
    r, t = np.meshgrid(R_NODES, T_NODES, indexing="ij")
    pts = np.column_stack([np.r_[0.0, (r * np.cos(t)).ravel()], np.r_[0.0, (r * np.sin(t)).ravel()],
                           np.zeros(1 + r.size)])
    return pts, np.repeat(pts, 6, axis=0), np.tile(np.arange(6), len(pts))


def field(pts, w, dwdx, dwdy):
    """A six-dof field: uz = w, rx = 50 dw/dy, ry = -50 dw/dx (rad), rz = 50 (a drilling rotation)."""
    u = np.zeros((len(pts), 6))
    u[:, 2], u[:, 3], u[:, 4], u[:, 5] = w, 50 * dwdy, -50 * dwdx, 50.0
    return u.ravel()


@pytest.mark.parametrize("shape, label", [("r2cos2t", (2, 0)), ("1-2r2", (0, 1))])
def test_labels_of_six_dof_fields(shape, label):
    pts, X, D = disc()
    x, y = pts[:, 0], pts[:, 1]
    if shape == "r2cos2t":  # r^2 cos 2t = x^2 - y^2
        phi = field(pts, x**2 - y**2, 2 * x, -2 * y)
    else:
        phi = field(pts, 1 - 2 * (x**2 + y**2), -4 * x, -4 * y)
    assert np.abs(phi).max() >= 50 * np.abs(phi[D == 2]).max()  # rotations lead by far
    lab = ModeLabeler.from_dofs(X, D, radius=1.0)
    assert lab.label_dofs(phi) == label
    # the node order of a labeler from dofs is its own: shuffling the dofs changes nothing
    perm = np.random.default_rng(0).permutation(len(D))
    assert ModeLabeler.from_dofs(X[perm], D[perm], radius=1.0).label_dofs(phi[perm]) == label


def test_rim_held_by_a_shell_condition():
    pts, _, _ = disc()
    rim = np.flatnonzero(np.isclose(np.hypot(pts[:, 0], pts[:, 1]), 1.0))
    fixed = np.zeros((len(pts), 6), dtype=bool)
    fixed[rim, 3:] = True  # the rotations alone hold no displacement
    assert not edge_is_held(pts, np.arange(len(pts)), fixed.ravel(), 1.0, float("inf"))
    fixed[rim, 2] = True  # uz on the rim: a simply supported plate
    assert edge_is_held(pts, np.arange(len(pts)), fixed.ravel(), 1.0, float("inf"))
    assert edge_is_held(pts, np.arange(len(pts)), fixed[:, :3].ravel(), 1.0, float("inf"))  # a solid's 3 N
