"""Invariant manifolds of several master modes (internal resonances, issue 33).

:mod:`~stepnf.dpim.multimode.manifold` parametrises the manifold (complex normal form, full order, from the black
box's forces and shifted solves: :mod:`~stepnf.dpim.multimode.monomials` for the multi-indices and the forcing
sampled at real points, :mod:`~stepnf.dpim.multimode.solves` for one factorisation per shift);
:mod:`~stepnf.dpim.multimode.branches` holds the periodic-orbit equations of its reduced dynamics (the backbone
branches, their stability), :mod:`~stepnf.dpim.multimode.starts` finds where they start,
:mod:`~stepnf.dpim.multimode.continuation` traces them, :mod:`~stepnf.dpim.multimode.symmetry` finds the rotations
of exact twins they must be traced modulo, :mod:`~stepnf.dpim.multimode.measures` measures them like the
single-mode backbone and
:mod:`~stepnf.dpim.multimode.backbone` gives the branches of one master, their frequency at an amplitude and their
validity from orders N-2 and N.
"""
