"""Mode labels of the FEniCSx adapters: :class:`stepnf.geometry.labels.ModeLabeler` and the held-edge convention.

A plate or shell whose edge is held (its transverse displacement zero all
along the rim: clamped or simply supported) labels its modes ``(k, n)`` with
``n`` counting the edge as a nodal circle, as the clamped-edge von Karman model
does (:mod:`stepnf.models.vonkarman`): the clamped plate's fundamental is
``(0, 1)``, then ``(1, 1)``, ``(2, 1)``, ``(0, 2)``, so a scene's
``master_modes`` name the same modes whatever the solver.
"""
from __future__ import annotations

from stepnf.geometry.labels import ModeLabeler, count_edge_circle, edge_is_held

__all__ = ["ModeLabeler", "count_edge_circle", "edge_is_held"]
