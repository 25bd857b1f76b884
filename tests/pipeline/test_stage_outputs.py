"""The stages' typed outputs (:mod:`stepnf.pipeline.outputs`) and the commands that reuse the stages.

* Every output is frozen: assigning a field raises ``FrozenInstanceError``.
* ``run_scene`` calls each stage once, in order, and the outputs fit together (the masters' STEP terms,
  records and backbones are those of the modes stage's masters).
* ``stepnf modes`` and ``stepnf verify`` build the scene's model once (before: ``stepnf verify`` built the
  adapter and read K, M a second time after the run) and read K and M once.
* A model in modal coordinates returns the same :class:`Evaluations` and :class:`Backbones` as an adapter.
"""
from __future__ import annotations

import dataclasses

import pytest

import stepnf.pipeline.model as model_module
import stepnf.pipeline.run as run_module
from stepnf.pipeline.outputs import (AdapterFacts, BackboneOutput, Backbones, Evaluations, RunContext, RunModel,
                                     RunModes, StepTerms)
from stepnf.pipeline.state import StageView
from stepnf.methods import MODAL
from stepnf.runtime.progress import Progress
from stepnf.scene.parse import load_scene
from helpers.scenes import polynomial_scene, write_two_dof_scene

STAGES = ("model_stage", "backbone_check_stage", "modes_stage", "step_stage", "evaluators_stage",
          "backbone_stage", "output_mesh_stage", "results_stage")


@pytest.fixture
def scene(tmp_path):
    return load_scene(polynomial_scene(tmp_path))


@pytest.fixture
def outputs(scene):
    ctx = RunContext.start(scene, Progress(enabled=False))
    adapter = model_module.open_model(scene)
    try:
        yield ctx, run_module.run_adapter(ctx, adapter)
    finally:
        adapter.close()


def test_every_stage_output_is_frozen(outputs):
    ctx, (model, modes, terms, evals, backbones, facts) = outputs
    for value, name in ((ctx, "scene"), (model, "K"), (modes, "basis"), (terms, "steps"), (evals, "modes"),
                        (backbones, "by_master"), (facts, "description"), (backbones.by_master[0], "block"),
                        (StageView(ctx, model), "model")):
        assert dataclasses.is_dataclass(value)
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(value, name, None)
    with pytest.raises(AttributeError):  # the view's names are read-only properties
        StageView(ctx, model).K = None


def test_the_outputs_fit_together(outputs):
    _, (model, modes, terms, evals, backbones, facts) = outputs
    assert isinstance(model, RunModel) and model.K.shape == (6, 6) and model.forces is not None
    assert isinstance(modes, RunModes) and modes.masters == [0]
    assert isinstance(terms, StepTerms) and list(terms.steps) == [0] and terms.full is None
    assert isinstance(evals, Evaluations) and [r.index for r in evals.modes] == [0] and list(evals.Gv) == [0]
    assert isinstance(backbones, Backbones) and list(backbones.results) == [0]
    assert isinstance(backbones.by_master[0], BackboneOutput) and "backbone_0_Y" in backbones.by_master[0].arrays
    assert isinstance(facts, AdapterFacts) and facts.output_mesh is None  # no field files asked for


def test_run_scene_calls_each_stage_once_in_order(scene, monkeypatch):
    calls = []
    for name in STAGES:
        stage = getattr(run_module, name)

        def counted(*args, _stage=stage, _name=name, **kw):
            calls.append(_name)
            return _stage(*args, **kw)
        monkeypatch.setattr(run_module, name, counted)
    result = run_module.run_scene(scene, write=False)
    assert calls == list(STAGES)
    # the result is the results stage's: the backbone block is on the record, the arrays gathered there
    assert result.modes[0].backbone is not None and "backbone_0_Y" in result.arrays
    assert list(result.arrays)[:2] == ["omega", "master_modes"] and "Gv_0" in result.arrays


def count_builds(monkeypatch) -> dict[str, int]:
    """Count the models built and the K, M read (``checked_matrices``) from now on."""
    import stepnf.pipeline.model as m

    counts = {"built": 0, "matrices": 0}
    build, matrices = m.build_model, m.checked_matrices

    def built(scene):
        counts["built"] += 1
        return build(scene)

    def read(adapter):
        counts["matrices"] += 1
        return matrices(adapter)
    monkeypatch.setattr(m, "build_model", built)
    monkeypatch.setattr(m, "checked_matrices", read)
    return counts


def test_stepnf_modes_builds_the_model_once(scene, monkeypatch):
    from stepnf.cli.modes import modal_survey

    counts = count_builds(monkeypatch)
    survey = modal_survey(scene)
    assert counts == {"built": 1, "matrices": 1}
    assert survey.n_dofs == 6 and survey.masters == [0]


def test_stepnf_verify_builds_the_model_once(tmp_path, monkeypatch):
    """One adapter for the run and the orbits (two before): K and M from the run's model stage."""
    from stepnf.verify.command import verify_scene

    scene = load_scene(write_two_dof_scene(tmp_path, backbone="\n[analysis.backbone]\norder = 5\npoints = 4\n"))
    counts = count_builds(monkeypatch)
    doc = verify_scene(scene, amplitudes=[0.1])
    assert counts == {"built": 1, "matrices": 1}
    assert doc["n_dofs"] == 2 and len(doc["modes"][0]["checks"]) == 1


def test_a_modal_model_returns_the_same_typed_values(tmp_path):
    from stepnf.pipeline.modal_coordinates import ModalSpectrum, modal_model_outputs

    path = tmp_path / "vk.toml"
    path.write_text('[model]\nsolver = "vonkarman"\nedge = "clamped"\nkappa = 10.0\n[analysis]\n'
                    'master_modes = ["(0,1)"]\nmethods = ["nf"]\n[analysis.backbone]\norder = 3\n'
                    '[output]\ndir = "out"\n')
    scene = load_scene(path)
    model = model_module.open_model(scene)
    try:
        assert not model_module.is_modal_model(load_scene(polynomial_scene(tmp_path)))
        assert model_module.is_modal_model(scene)
        spectrum, evals, backbones = modal_model_outputs(RunContext.start(scene, Progress(enabled=False),
                                                                          order=MODAL), model)
    finally:
        model.close()
    assert isinstance(spectrum, ModalSpectrum) and isinstance(evals, Evaluations)
    assert isinstance(backbones, Backbones)
    p = spectrum.masters[0]
    assert [r.index for r in evals.modes] == [p] and backbones.by_master[p].result is not None
    with pytest.raises(dataclasses.FrozenInstanceError):
        evals.modes = []
