"""Where a master's backbone branches start: the periodic orbits of the reduced dynamics at a small amplitude.

At a small amplitude ``r`` of ``zeta_j``, Newton at fixed ``Re zeta_j = r`` (:meth:`stepnf.dpim.multimode.branches.
ReducedSystem.correct`) from guesses: the linear mode with the others forced at their lowest order (``zeta_l =
f zeta^alpha / (i (k_l Omega - w_l))``), the closed-form coupled solutions of an exact or near 1:2 pair
(quadratic coupling: ``delta (2 delta + mu) = - f_a f_b r^2``, ``delta = k_j Omega - w_j``,
``mu = 2 w_j - w_l``), at any other exact resonance (1:3, 1:4, ...) the linear mode's guess at Omega detuned by
mode j's own cubic shift and a grid of ``zeta_l`` (magnitudes and phases) and, for a 1:1 pair, ``zeta_l = +-zeta_j,
i zeta_j`` (in-phase, out-of-phase, elliptic). A standing wave of exact twins is solved with the rotation's phase
condition and unfolding (:mod:`stepnf.dpim.multimode.symmetry`).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from stepnf.dpim.multimode.branches import ReducedSystem

#: A starting point is new when its (Omega, zeta) differ from the others' by more than this (relative).
DISTINCT = 1e-6


def _fixed_amplitude(j: int, r: float, n: int) -> Callable[[np.ndarray], tuple[float, np.ndarray]]:
    """``Re zeta_j = r`` as :meth:`ReducedSystem.correct`'s extra equation, in ``n`` unknowns."""
    g = np.zeros(n)
    g[j] = 1.0
    return lambda u: (float(u[j] - r), g)


def start_guesses(system: ReducedSystem, j: int, r: float) -> list[tuple[str, np.ndarray]]:
    """``(kind, zeta)`` guesses at ``zeta_j = r`` (module docstring) and their ``Omega``s, as ``u`` vectors."""
    m, k, w = system.m, system.k, system.omega
    Om0 = w[j] / k[j]
    out = []

    def u_of(zeta, Om):
        return np.concatenate([zeta.real, zeta.imag, [Om, 0.0]])

    own = np.array([(system.eq == l) & np.all(np.delete(system.E, [j, j + m], axis=1) == 0, axis=1)
                    for l in range(m)])  # monomials of equation l made of mode j only
    base = np.zeros(m, dtype=complex)
    base[j] = r
    coupled = []
    # mode j's own cubic frequency shift: at an exact k_l Om0 = w_l the guess below needs Omega off Om0
    cubic = (system.eq == j) & np.all(system.E == _unit(2 * m, [j, j, j + m]), axis=1)
    Om_base = Om0
    for l in range(m):
        if l == j or not own[l].any():
            continue
        idx = np.flatnonzero(own[l])
        deg = system.E[idx].sum(axis=1)
        i0 = idx[deg == deg.min()]
        forcing = complex(np.sum(system.c[i0])) * r ** int(deg.min())
        sigma = k[l] * Om0 - w[l]
        back = (system.eq == j) & np.all(system.E == _unit(2 * m, [j + m, l]), axis=1)
        closed = int(deg.min()) == 2 and 2 * k[j] == k[l] and back.any()
        if abs(sigma) <= 1e-8 * w[l] and k[l] != k[j] and not closed:  # exact 1:3, 1:4, ...: shifted, grid
            Om_base = (w[j] + float(np.sum(system.c[cubic]).imag) * r * r) / k[j]
            sigma = k[l] * Om_base - w[l]
            coupled += _grid_guesses(m, j, l, r, Om_base)
        if abs(sigma) > 1e-8 * w[l]:
            base[l] = forcing / (1j * sigma)
        if closed:  # a 1:2 pair: the closed-form coupled solutions
            fa, fb = complex(system.c[back][0]), complex(system.c[i0][0])
            mu = k[l] * Om0 - w[l]  # = 2 w_j - w_l for k = (1, 2)
            disc = np.sqrt(complex(mu * mu - 8 * fa * fb * r * r))
            for sgn in (1, -1):
                delta = (-mu + sgn * disc) / 4
                if abs(delta.imag) > 1e-9 * abs(w[j]):  # no real root: no coupled branch here
                    continue
                zeta = np.zeros(m, dtype=complex)
                zeta[j] = r
                sig = k[l] * (w[j] + delta.real) / k[j] - w[l]
                zeta[l] = fb * r * r / (1j * sig) if sig != 0 else 0
                coupled.append(("coupled", u_of(zeta, (w[j] + delta.real) / k[j])))
    out.append((f"continues mode {j}", u_of(base, Om_base)))
    out += coupled
    for l in range(m):  # 1:1 pairs: in-phase, out-of-phase, elliptic
        if l != j and k[l] == k[j]:
            for ph in (1, -1, 1j):
                zeta = base.copy()
                zeta[l] = ph * r
                out.append(("coupled", u_of(zeta, Om0)))
    return out


def _grid_guesses(m: int, j: int, l: int, r: float, Om: float) -> list[tuple[str, np.ndarray]]:
    """Coupled guesses of an exact resonance with no closed form (1:3, 1:4, ...): ``zeta_l = s e^{i psi}``,
    ``s`` from ``r / 100`` to ``10 r`` (7 values), ``psi`` every ``pi / 4``; :func:`starts` keeps the distinct
    solutions Newton reaches."""
    out = []
    for s in r * np.logspace(-2.0, 1.0, 7):
        for psi in np.arange(8) * np.pi / 4:
            zeta = np.zeros(m, dtype=complex)
            zeta[j], zeta[l] = r, s * np.exp(1j * psi)
            out.append(("coupled", np.concatenate([zeta.real, zeta.imag, [Om, 0.0]])))
    return out


def _unit(n: int, where: list[int]) -> np.ndarray:
    e = np.zeros(n, dtype=int)
    for i in where:
        e[i] += 1
    return e


def starts(system: ReducedSystem, j: int, r: float) -> list[tuple[str, np.ndarray, ReducedSystem]]:
    """The distinct periodic orbits (the equations (*) of :mod:`stepnf.dpim.multimode.branches`) at ``Re zeta_j = r``
    reached by Newton from :func:`start_guesses`: ``(kind, u, system)``, ``system`` with the rotations the point
    needs (:meth:`ReducedSystem.for_point`: a standing wave of exact twins; ``u`` then carries their unfoldings)."""
    m = system.m
    gens = system.rotations()
    found: list[tuple[str, np.ndarray, ReducedSystem]] = []
    for kind, u in start_guesses(system, j, r):
        guess = u[:m] + 1j * u[m:2 * m]
        sub = system.for_point(guess, gens)
        u = np.concatenate([u[:2 * m + 2], np.zeros(len(sub.R))])
        ref = np.zeros(m, dtype=complex)
        ref[j] = 1.0
        done = sub.correct(u, _fixed_amplitude(j, r, sub.n), ref, maxiter=40, turned=guess)
        if done is None:
            continue
        v = done[0]
        if np.abs(v[2 * m + 1:]).max() > 1e-8 * system.omega.max():  # eps (and mu) vanish on a periodic orbit
            continue
        if any(np.abs(v[:2 * m + 2] - w[:2 * m + 2]).max() <= DISTINCT * max(1.0, np.abs(w).max())
               for _, w, _ in found):
            continue
        found.append((kind, v, sub))
    return found
