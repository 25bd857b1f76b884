"""(k, n) labels of the modes of axisymmetric shells from their transverse displacement (numpy/scipy).

A mode is *transverse* when the normal component of its mid-surface
displacement carries at least half of the mid-surface displacement's
squared norm. Its transverse displacement ``w`` is interpolated (linearly,
from the scattered mid-surface nodes) onto a polar grid of the plan view;
``k`` (nodal diameters) is the angular Fourier order with the largest
area-weighted energy, ``n`` (nodal circles) the number of sign changes of the
radial profile of that Fourier component (values under ``threshold`` of its
maximum are ignored, so the centre of a ``k >= 1`` mode, where the profile
vanishes like ``r^k``, does not count). Other modes (and modes whose
mid-surface hardly moves: mean squared displacement under ``mid_fraction`` of
that of all nodes) are ``"thickness"`` when
their normal displacement dominates away from the mid-surface (through-thickness
stretching) and ``"in-plane"`` otherwise.

Only translations are displacements: a shell adapter (six dofs per node, rotations ``rx ry rz`` in
radians) builds its labeler with :meth:`ModeLabeler.from_dofs` and labels its fields with
:meth:`ModeLabeler.label_dofs`, which read each node's translation from the dof directions, so a mode
whose largest entry is a rotation is labelled by its displacement (a plain ``reshape(-1, 3)`` of six dofs
per node would mix rotations into the displacements).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from stepnf.geometry.cap import outward_normals
from stepnf.plugin.dofs import node_vectors


class ModeLabeler:
    """Labels modes from node displacements.

    Parameters
    ----------
    plan : (p, 2) plan-view coordinates of the mid-surface nodes
    mid : (p,) indices of those nodes among the displacement nodes
    normals : (N, 3) unit normals at every displacement node
    radius : outer radius of the plan view
    """

    def __init__(self, plan: np.ndarray, mid: np.ndarray, normals: np.ndarray, radius: float,
                 *, n_r: int = 48, n_theta: int = 128, threshold: float = 0.01, max_k: int = 30,
                 mid_fraction: float = 0.05):
        from scipy.spatial import Delaunay

        self.mid = np.asarray(mid)
        self.normals = np.asarray(normals, dtype=float)
        self.threshold = threshold
        self.mid_fraction = mid_fraction
        self.max_k = max_k
        self.r = np.linspace(0.01, 0.99, n_r) * radius
        self.theta = np.linspace(0.0, 2 * np.pi, n_theta, endpoint=False)
        Rg, Tg = np.meshgrid(self.r, self.theta, indexing="ij")
        self._tri = Delaunay(np.asarray(plan, dtype=float))
        self._query = np.column_stack([(Rg * np.cos(Tg)).ravel(), (Rg * np.sin(Tg)).ravel()])

    #: dof coordinates and directions of a labeler built by :meth:`from_dofs`
    _dofs: tuple[np.ndarray, np.ndarray] | None = None

    @classmethod
    def from_dofs(cls, coordinates: Any, directions: Any, radius: float, R: float = float("inf"),
                  **kw: Any) -> "ModeLabeler":
        """A labeler of a mid-surface model (a shell: every node on the mid-surface) from its dof coordinates
        (n, 3) and direction codes (n,) (:data:`~stepnf.plugin.adapter.DIRECTIONS`): nodes told apart by
        their coordinates, normals of the sphere of radius ``R`` (``inf``: a plate), plan radius ``radius``."""
        X, D = np.asarray(coordinates, dtype=float), np.asarray(directions)
        nodes, _ = node_vectors(np.zeros(len(D)), X, D)
        out = cls(nodes[:, :2], np.arange(len(nodes)), outward_normals(nodes, float(R)), radius, **kw)
        out._dofs = (X, D)
        return out

    def label_dofs(self, phi: np.ndarray):
        """Label of one mode given as a dof field (n,) of the labeler's :meth:`from_dofs` model: its node
        translations only (rotation dofs are not displacements)."""
        if self._dofs is None:
            raise ValueError("label_dofs needs a labeler built by ModeLabeler.from_dofs")
        return self.label(node_vectors(phi, *self._dofs)[1])

    def _interp(self, w_mid: np.ndarray) -> np.ndarray:
        from scipy.interpolate import LinearNDInterpolator

        vals = LinearNDInterpolator(self._tri, w_mid, fill_value=0.0)(self._query)
        return vals.reshape(len(self.r), len(self.theta))

    def split(self, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normal (N,) and tangential (N, 3) parts of node displacements ``U`` (N, 3)."""
        w = np.einsum("ij,ij->i", U, self.normals)
        return w, U - w[:, None] * self.normals

    def label(self, U: np.ndarray):
        """Label of one mode given its node displacements ``U`` (N, 3)."""
        w, t = self.split(U)
        wm, tm = w[self.mid], t[self.mid]
        e_mid = np.sum(wm**2) + np.sum(tm**2)
        # mean squared mid-surface displacement against that of every node
        still_mid = e_mid / len(wm) < self.mid_fraction * (np.sum(w**2) + np.sum(t**2)) / len(w)
        if still_mid or np.sum(wm**2) < np.sum(tm**2):
            return "thickness" if np.sum(w**2) > np.sum(t**2) else "in-plane"
        W = self._interp(wm)
        C = np.fft.rfft(W, axis=1) / W.shape[1]
        kmax = min(self.max_k, C.shape[1] - 1)
        energy = (np.abs(C[:, : kmax + 1]) ** 2 * self.r[:, None]).sum(axis=0)
        k = int(np.argmax(energy))
        c = C[:, k]
        phase = 0.5 * np.angle(np.sum(self.r * c**2))
        profile = np.real(c * np.exp(-1j * phase))
        big = profile[np.abs(profile) > self.threshold * np.abs(profile).max()]
        n = int(np.count_nonzero(np.diff(np.sign(big)) != 0))
        return (k, n)


def count_edge_circle(labels: list[Any]) -> list[Any]:
    """``(k, n + 1)`` for every ``(k, n)`` label, other labels unchanged: the convention of a plate or shell
    whose edge is held (normal displacement zero all along the rim, clamped or simply supported), whose
    edge counts as a nodal circle as in the clamped-edge von Karman model (:mod:`stepnf.models.vonkarman`):
    the clamped plate's fundamental is ``(0, 1)``, then ``(1, 1)``, ``(2, 1)``, ``(0, 2)``, whatever the
    solver, so a scene's ``master_modes`` name the same modes in every model."""
    return [(lab[0], lab[1] + 1) if isinstance(lab, tuple) and len(lab) == 2 else lab for lab in labels]


def edge_is_held(points: np.ndarray, mid: np.ndarray, fixed: np.ndarray, a: float, R: float) -> bool:
    """True when the fixed dofs zero the normal displacement at every mid-surface node of the rim.

    ``points`` (N, 3) node coordinates, ``mid`` indices of the mid-surface nodes among them, ``fixed``
    (k N,) bool, dof ``k i + c`` of node ``i`` in direction ``c`` fixed (``k = 3`` for a solid, 6 for a shell
    whose directions 3-5 are rotations, which do not hold the displacement); the rim is the mid-surface nodes
    at plan radius ``a`` (to 1e-6 relative), ``R`` the sphere's radius (``inf``: flat) giving the normals.
    A clamped or simply supported edge is held; a free one, or one held only in-plane, is not.
    """
    mid = np.asarray(mid)
    X = points[mid]
    rim = mid[np.hypot(X[:, 0], X[:, 1]) >= float(a) * (1 - 1e-6)]
    if rim.size == 0:
        return False
    free_dirs = ~np.asarray(fixed, dtype=bool).reshape(len(points), -1)[rim, :3]
    normals = outward_normals(points[rim], float(R))
    return bool(np.all(np.abs(normals[free_dirs]) <= 1e-12))
