"""The geometry of the example truss: a parabolic arch of box cross-section, made of pin-jointed bars.

Station ``i`` (``i = 0 .. panels``) sits at ``x = span i / panels``; its top
chord at ``z(x) = 4 rise x (span - x) / span^2`` and its bottom chord
``depth`` below. Each station has four nodes (node ``4 i + k``):

====  =================  ===========
k     chord              y
====  =================  ===========
0     top                -width / 2
1     top                +width / 2
2     bottom             -width / 2
3     bottom             +width / 2
====  =================  ===========

Bars: four chords per panel, a top tie, a bottom tie, two posts and one
diagonal per station, and one diagonal in each of the four faces of every
panel. Every face is triangulated, so the free truss moves only rigidly (six
rigid-body modes). Named node sets (for ``[[model.boundary]]``): ``left``
(station 0), ``right`` (the last station) and ``ends`` (both).
Lengths are in the model's units (the scene's), whatever they are.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Truss:
    """Nodes ``points`` (nn, 3), bars ``bars`` (m, 2) of node indices, and named node sets."""

    points: np.ndarray
    bars: np.ndarray
    node_sets: dict[str, np.ndarray]


def arched_box_truss(span: float, rise: float, depth: float, width: float, panels: int) -> Truss:
    """The arched box girder described in the module docstring."""
    x = np.linspace(0.0, span, panels + 1)
    z_top = 4.0 * rise * x * (span - x) / span**2
    points = np.zeros((panels + 1, 4, 3))
    points[:, :, 0] = x[:, None]
    points[:, :, 1] = np.array([-0.5, 0.5, -0.5, 0.5]) * width
    points[:, :, 2] = z_top[:, None] - np.array([0.0, 0.0, depth, depth])
    bars = []
    for i in range(panels + 1):
        a = 4 * i
        bars += [(a, a + 1), (a + 2, a + 3), (a, a + 2), (a + 1, a + 3), (a, a + 3)]  # ties, posts, diagonal
        if i < panels:
            b = a + 4
            bars += [(a + k, b + k) for k in range(4)]  # chords
            bars += [(a, b + 2), (a + 1, b + 3), (a, b + 1), (a + 2, b + 3)]  # face diagonals
    last = 4 * panels + np.arange(4)
    sets = {"left": np.arange(4), "right": last, "ends": np.concatenate([np.arange(4), last])}
    return Truss(points.reshape(-1, 3), np.asarray(bars, dtype=np.int64), sets)
