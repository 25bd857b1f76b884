"""Continuous symmetries of a manifold's reduced dynamics: the rotations of exact twin masters.

Both companions of an axisymmetric structure's mode (n >= 1 nodal diameters) on one manifold give reduced dynamics
that commute with a rotation of the pair, ``(zeta_c, zeta_s) -> (cos t zeta_c - sin t zeta_s, sin t zeta_c + cos t
zeta_s)`` (other pairs of the manifold turning ``q`` times as fast), generator ``R`` (real, ``m x m``, acting on
``zeta``). Every standing wave then lies on a one-parameter family of turned ones and carries a second first
integral (the angular momentum, gradient ``i R zeta``): the periodic-orbit equations of
:class:`stepnf.dpim.multimode.branches.ReducedSystem` lose one more rank there, and a standing wave is traced with
one more unfolding and one more phase condition (that module's docstring). :func:`rotations` finds the generators
from the coefficients alone, :func:`needed` says which a point needs (a standing wave: ``R zeta`` independent of the
time shift ``i k zeta``; a travelling wave, which a rotation only shifts in time, needs none).

``system`` below: a :class:`~stepnf.dpim.multimode.branches.ReducedSystem` (``m``, ``k``, ``omega``, ``eq``, ``E``,
``c``).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from stepnf.dpim.multimode.monomials import values_and_partials

#: A rotation of twin masters is a symmetry of the reduced dynamics when it commutes with each homogeneous part of
#: the field to this (relative, :func:`rotation_misfit`). Measured: exact twins commute to the coefficients'
#: round-off, 1.0e-14 .. 1.5e-13 (the O(2)-symmetric 2-dof system of tests/dpim/test_branches.py, orders 5 .. 13)
#: and 3.9e-15 .. 1.4e-14 (the von Karman cap's (2,1) and (4,0) pairs, orders 5 .. 9); that 2-dof system with its
#: coupling 1e-6 off the symmetric one misses by 1.0e-6 .. 7.1e-6, and twins split in frequency (the 3D O-grid's, by
#: 3e-4) miss by ~1e-4 by their linear part alone: not exact, traced as they are (their turned standing waves
#: nearly, not exactly, degenerate).
SYMMETRY_TOL = 1e-8
#: ``R zeta`` counts as independent of the time shift ``i k zeta`` (a standing wave, not a travelling one) when the
#: smaller singular value of the two (normalised) directions exceeds this.
ORBIT_TOL = 1e-6


def rotations(system: Any) -> np.ndarray:
    """The generators ``R`` (s, m, m) of the rotations of masters that commute with the field: those of
    :func:`rotation_misfit` below :data:`SYMMETRY_TOL`. Empty when there is none."""
    misfit, gens = rotation_misfit(system)
    keep = gens[misfit <= SYMMETRY_TOL]
    return keep if len(keep) else np.zeros((0, system.m, system.m))


def rotation_misfit(system: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(misfit, R)``: the candidate rotations ``R`` (p, m, m) and how far each is from commuting with the field
    (p,), relative, best first.

    Candidates: ``R = sum_p q_p R_p``, ``R_p`` turning a pair (i, l) of masters with ``k_i = k_l``
    (``R_p e_i = e_l``, ``R_p e_l = -e_i``). ``R`` is a symmetry when ``dF_d(zeta)[R zeta] = R F_d(zeta)`` for each
    homogeneous part ``F_d`` (d = 1: the linear part, which needs ``w_i = w_l``), linear in ``q``: the right singular
    vectors of that condition at four random ``zeta``, each part normalised by ``|F_d(zeta)|`` (scale-free), their
    singular values over the square root of the number of parts the misfit (no candidate: empty)."""
    m, k = system.m, system.k
    pairs = [(i, l) for i in range(m) for l in range(i + 1, m) if k[i] == k[l]]
    if not pairs:
        return np.zeros(0), np.zeros((0, m, m))
    gens = np.zeros((len(pairs), m, m))
    for p, (i, l) in enumerate(pairs):
        gens[p, l, i], gens[p, i, l] = 1.0, -1.0
    deg = system.E.sum(axis=1)
    rng = np.random.default_rng(0)
    blocks = []
    for _ in range(4):
        zeta = rng.standard_normal(m) + 1j * rng.standard_normal(m)
        mono, D = values_and_partials(zeta, system.E)
        for d in [1, *sorted(set(int(t) for t in deg))]:
            if d == 1:
                F = 1j * system.omega * zeta
                dF = [1j * system.omega * (g @ zeta) for g in gens]
            else:
                sel = deg == d
                F = np.zeros(m, dtype=complex)
                np.add.at(F, system.eq[sel], system.c[sel] * mono[sel])
                dF = []
                for g in gens:
                    v = g @ zeta
                    dv = D[sel, :m] @ v + D[sel, m:] @ np.conj(v)
                    out = np.zeros(m, dtype=complex)
                    np.add.at(out, system.eq[sel], system.c[sel] * dv)
                    dF.append(out)
            size = float(np.linalg.norm(F))
            if size == 0.0:
                continue
            cols = []
            for g, df in zip(gens, dF):
                r = (df - g @ F) / size
                cols.append(np.concatenate([r.real, r.imag]))
            blocks.append(np.column_stack(cols))
    _, sv, Vt = np.linalg.svd(np.vstack(blocks), full_matrices=True)
    sv = np.concatenate([sv, np.zeros(len(pairs) - len(sv))]) if len(sv) < len(pairs) else sv
    order = np.argsort(sv)
    return sv[order] / np.sqrt(len(blocks)), np.einsum("sp,pij->sij", Vt[order], gens)


def needed(system: Any, zeta: np.ndarray, gens: np.ndarray) -> np.ndarray:
    """The generators of ``gens`` (s, m, m) that turn ``zeta`` out of its time shift's direction ``i k zeta``
    (module docstring: standing waves of twins; travelling waves and motions the rotation leaves alone keep none),
    each independent of the ones kept before it: (s', m, m)."""
    m, keep = system.m, []
    dirs = [np.concatenate([(1j * system.k * zeta).real, (1j * system.k * zeta).imag])]
    for g in np.asarray(gens, dtype=float).reshape(-1, m, m):
        v = g @ zeta
        trial = np.column_stack(dirs + [np.concatenate([v.real, v.imag])])
        norms = np.linalg.norm(trial, axis=0)
        if np.all(norms > 0) and np.linalg.svd(trial / norms, compute_uv=False)[-1] > ORBIT_TOL:
            keep.append(g)
            dirs.append(trial[:, -1])
    return np.asarray(keep, dtype=float).reshape(-1, m, m)
