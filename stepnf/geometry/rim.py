"""The generated cap's resolution for the conditions at its rim: a held rim gets more rings, graded.

A rim the boundary conditions hold (clamped, simply supported: some dof of
every node of the lateral face fixed, :func:`rim_is_held`) bends sharply near
the edge, where the free rim's default O-grid (5 equal rings over the outer
half of the radius, each ~ 0.1 a) is too coarse: the clamped circular plate
(a / h = 50, nu = 0.3, 27-node hexahedra) came out +0.45%, +0.56%, +0.58%,
+0.75% above Leissa's w_bar = 10.2158, 21.260, 34.877, 39.771 (modes (0,1),
(1,1), (2,1), (0,2), the edge counted as a circle), 16 641 free dofs.
:func:`rim_resolution` gives a held rim :data:`HELD_N_RING` rings whose
radial widths fall by :data:`HELD_GRADING` towards the edge
(:func:`stepnf.geometry.cap.graded_nodes`): +0.16%, +0.14%, +0.09%, +0.13%
with 22 689 free dofs (+36%). Measured (same plate, n_core 14): 8 equal rings
+0.22% at most, 8 rings graded 3 +0.15%, 7 rings graded 2 +0.22%; grading the
5 default rings alone does not help (+0.63% at grading 2, worse beyond), the
rings are too coarse everywhere, not only at the edge. Simply supported
(``uz`` fixed on the rim): within 0.17% of 4.935, 13.898, 25.613, 29.720
before and after.

Halving every element twice from (n_core, n_ring) = (7, 4) to (28, 16), rings
graded 2: observed order 2.1 .. 2.6 (the clamped solid edge's corner
singularity keeps Q2 below its smooth h^4), Richardson limit 0.03% .. 0.26%
below Leissa (the solid's own shear at a / h = 50; tests/geometry/test_held_rim.py).

A free rim keeps the mesh it always had (:data:`~stepnf.geometry.cap.DEFAULT_N_RING`
equal rings), node for node. A resolution the scene gives (``n_ring``,
``grading``, either one) is kept as given: the held-rim defaults apply only
when the scene gives neither, so a pinned clamped mesh is the one it always was. :func:`cap_for_conditions` is the one place
that applies this, for every generated cap: the fenicsx adapter's
(:meth:`stepnf_fenicsx.FenicsxAdapter.cap`, 27-node hexahedra) and the
calculix and code_aster ones (:func:`stepnf.external.keys.build_solid`,
20-node hexahedra). With C3D20 (one element through the thickness) the same
clamped plate came out +0.98%, +1.11%, +1.14%, +1.31% at the free rim's
defaults (9 585 free dofs) and +0.38%, +0.37%, +0.32%, +0.35% with the held
rim's (13 113 free dofs; tests/solvers/calculix/test_calculix_boundary.py).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from stepnf.plugin.boundary import BoundaryCondition, select_nodes
from stepnf.geometry.cap import VolumeMesh, spherical_cap

#: Rings across the O-grid's ring block when the conditions hold the rim (5 when free).
HELD_N_RING = 8
#: Radial width of the innermost ring over the outermost one when the conditions hold the rim (1 when free).
HELD_GRADING = 2.0


def rim_is_held(mesh: VolumeMesh, conditions: Sequence[BoundaryCondition], scene_file: str | Path | None = None
                ) -> bool:
    """True when ``conditions`` fix at least one dof of every node of the rim (the node set ``"edge"`` of a
    generated cap); ``False`` without conditions or without such a set. A set the mesh lacks, or a box
    holding no node, is the :class:`~stepnf.errors.SceneError` of :func:`stepnf.plugin.boundary.select_nodes`."""
    rim = mesh.node_sets.get("edge")
    if rim is None or len(rim) == 0 or not conditions:
        return False
    held = np.zeros(mesh.n_points, dtype=bool)
    for bc in conditions:
        if bc.dofs:
            held[select_nodes(bc, mesh.points, mesh.node_sets, scene_file)] = True
    return bool(held[np.asarray(rim)].all())


def rim_resolution(resolution: Mapping[str, Any], held: bool) -> dict[str, Any]:
    """``resolution`` (keyword arguments of :func:`~stepnf.geometry.cap.spherical_cap`) completed for a
    held rim: ``n_ring`` :data:`HELD_N_RING` and ``grading`` :data:`HELD_GRADING` when it gives neither
    (``n_core`` alone does not pin the rings); a free rim's, or one that gives ``n_ring`` or ``grading``,
    is returned as given (a scene that pins its mesh keeps its figures)."""
    out = dict(resolution)
    if held and "n_ring" not in out and "grading" not in out:
        out.update(n_ring=HELD_N_RING, grading=HELD_GRADING)
    return out


def cap_for_conditions(a: float, R: float, h: float, conditions: Sequence[BoundaryCondition], *,
                       element: str, scene_file: str | Path | None = None, **resolution: Any
                       ) -> tuple[VolumeMesh, dict[str, Any]]:
    """The generated cap (:func:`~stepnf.geometry.cap.spherical_cap`; a, R, h in the scene's length unit,
    ``R = inf``: flat plate) of ``element`` for the boundary ``conditions``, and the resolution it was built
    with: ``resolution`` itself when the conditions leave the rim free, :func:`rim_resolution`'s when they
    hold it (:func:`rim_is_held`, judged on the mesh of ``resolution``). Errors are those of
    :func:`~stepnf.geometry.cap.spherical_cap` (ValueError) and :func:`rim_is_held` (SceneError)."""
    given = dict(resolution)
    mesh = spherical_cap(a, R, h, element=element, **given)
    full = rim_resolution(given, rim_is_held(mesh, conditions, scene_file))
    if full != given:
        mesh = spherical_cap(a, R, h, element=element, **full)
    return mesh, full
