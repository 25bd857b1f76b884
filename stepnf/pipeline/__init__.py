"""The run of a scene as a sequence of stages, each a function of the earlier stages' frozen outputs
(:mod:`.outputs`) and of the run's context, returning its own.

For a solver adapter (:func:`stepnf.pipeline.run.run_adapter` runs them in this order):

``model`` (:mod:`.model`: also :func:`~.model.open_model`, the model of the scene's kind)
    mass and stiffness matrices, the STEP policy the adapter allows, dof geometry, the checks that
    refuse a model before any solve.
``backbone_check`` (:mod:`.backbone`)
    with ``[analysis.backbone]``: what it asks of the model (a thickness for ``w_over_h``), before any solve.
``modes`` (:mod:`.modes`)
    the eigen-solve, mode labels, the master modes, the run's model flags.
``step`` (:mod:`.step`)
    the STEP force (or tangent) evaluations: targeted per master, and the full plan when asked.
``evaluators`` (:mod:`.evaluate`, :mod:`.apply_method`, :mod:`.master`, :mod:`.context`)
    NF/DNF, MD, SMD and the diagnostics of every master mode, with the full-order linear algebra
    built once, on first use.
``backbone`` (:mod:`.backbone`)
    with ``[analysis.backbone]``: the DPIM of every master mode to order N and its backbone curve.
``output_mesh`` (:mod:`.output_mesh`)
    the adapter's mesh for the field files, when the run writes them (:mod:`stepnf.io.fields`), its
    free-dof map and description.
``results`` (:mod:`.results`)
    once the adapter is closed: the spectrum, counts, arrays and run flags gathered from the outputs into
    a :class:`stepnf.io.results.RunResult`, timed, and written (HDF5, field files); nothing changes it after.

A model given in modal coordinates (:class:`stepnf.plugin.modal_model.ModalModel`) runs the short
sequence of :mod:`.modal_coordinates`, returning the same :class:`~.outputs.Evaluations` and
:class:`~.outputs.Backbones`. A stage's helpers read the outputs through a read-only
:class:`~.state.StageView`. A new stage is a function returning a new frozen value, called in
:func:`stepnf.pipeline.run.run_adapter` and given to the stages that need it.
"""
