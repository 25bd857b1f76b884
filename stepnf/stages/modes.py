"""Stage ``modes``: the eigen-solve, the mode labels, the master modes and the model's run flags."""
from __future__ import annotations

import warnings
from typing import Callable

import numpy as np

from ..diagnostics import conditioning_flags, soft_mode_flags
from ..errors import ModelWarning
from ..modal import ModalBasis, lambda_scale, modal_analysis, orient_degenerate, probe_vector
from ..plan import check_elastic_modes, check_mechanism, resolve_masters
from .state import RunState


class ModeLabels:
    """The adapter's labels of a basis, asked once per basis size (the last one only is kept)."""

    def __init__(self, adapter):
        self.adapter = adapter
        self.cache: dict[int, list] = {}

    def of(self, basis: ModalBasis) -> list:
        key = basis.n_elastic
        if key not in self.cache:
            self.cache.clear()
            self.cache[key] = list(self.adapter.mode_labels(basis.phi))
        return self.cache[key]


def modes_needed(state: RunState) -> int:
    """Elastic modes to compute at least: two above the highest integer master, ``n_ret`` for modal sums."""
    int_masters = [m for m in state.scene.master_modes if isinstance(m, int)]
    need = max(int_masters, default=0) + 2
    return max(need, state.n_ret) if state.needs_modal else need


def first_batch(state: RunState) -> int | None:
    """Modes of the first eigen-solve when masters are labels: two per master (each may be one of a
    degenerate pair) and four more (the modes just above the highest one), at least
    :func:`modes_needed`; None (the eigen-solve's own default) when every master is an index. On the
    paper's cap (six labelled masters, the highest the 14th mode) that is one run of 16 modes where a
    first run of 6 had to be extended."""
    masters = state.scene.master_modes
    if not any(isinstance(m, str) for m in masters):
        return None
    return max(modes_needed(state), 2 * len(masters) + 4)


def enough_modes(state: RunState, labels: ModeLabels) -> Callable[[ModalBasis], bool]:
    """Whether a partial basis holds every master mode and the modes just above the highest one."""
    scene, tol = state.scene, state.tol

    def enough(b: ModalBasis) -> bool:
        labs = labels.of(b) if any(isinstance(x, str) for x in scene.master_modes) else [None] * b.n_elastic
        ms = resolve_masters(scene, labs, b.n_elastic, complete=False)
        if ms is None:
            return False
        # the 1:1 checks need the modes just above the highest master (1:2 is checked locally)
        return b.complete or b.omega[-1] >= (1 + tol.resonance) * max(b.omega[i] for i in ms)
    return enough


def modes_stage(state: RunState) -> None:
    """Compute the modes the scene needs, label them and pick the master modes.

    Reads ``scene``, ``adapter``, ``K``, ``M``, ``backend``, ``X``, ``dirs``, ``candidates``,
    ``smooth``, ``counters``. Writes ``basis`` (degenerate pairs oriented by a probe field that
    depends on positions only, so every solver picks the same twins), ``labels``, ``masters``,
    ``flags`` (conditioning, soft modes counted as rigid, too few modes for the modal sums) and
    ``arrays`` (``omega``, ``master_modes``). A scene asking for modes the model does not have is a
    :class:`~stepnf.errors.SceneError`.
    """
    scene, adapter, K, M = state.scene, state.adapter, state.K, state.M
    labels = ModeLabels(adapter)
    eig = adapter.eigenmodes if adapter.provides_eigenmodes else None
    with state.progress.stage("eigen", "modal analysis"):
        basis = modal_analysis(K, M, modes_needed(state), counters=state.counters,
                               rigid_tolerance=scene.rigid_tolerance, rigid_modes=scene.rigid_modes,
                               degeneracy_tolerance=scene.degeneracy_tolerance, max_modes=scene.max_modes,
                               backend=state.backend, eigensolver=eig, enough=enough_modes(state, labels),
                               rigid_candidates=state.candidates, progress=state.progress.message,
                               first_batch=first_batch(state))
    check_elastic_modes(scene, basis)
    check_mechanism(scene, adapter, basis)
    orient_degenerate(basis, M, probe_vector(state.X, state.dirs, state.n))  # the same twins whatever the solver
    labels.cache.clear()
    state.basis, state.labels = basis, labels.of(basis)
    state.masters = resolve_masters(scene, state.labels, basis.n_elastic, complete=True)
    assert state.masters is not None
    state.flags = conditioning_flags(basis, K, M, state.smooth)
    if scene.rigid_modes is None:  # a count the user gave is theirs to keep
        for fl in soft_mode_flags(basis.rigid_eigenvalues, lambda_scale(K, M), scene.rigid_tolerance):
            # stacklevel 3: reported where stepnf.pipeline starts the run (_compute), as before the split
            warnings.warn(fl["message"], ModelWarning, stacklevel=3)
            state.flags.append(fl)
    if state.needs_modal and state.m < state.n_ret:
        state.flags.append({"kind": "fewer_modes", "message": f"only {state.m} elastic modes available, "
                            f"{state.n_ret} asked for in the modal sums"})
    state.arrays = {"omega": basis.omega, "master_modes": np.asarray(state.masters)}
