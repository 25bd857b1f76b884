"""The run of a scene as a sequence of stages sharing one :class:`~stepnf.stages.state.RunState`.

For a solver adapter (:func:`stepnf.pipeline.run_scene` runs them in this order):

``model`` (:mod:`.model`)
    mass and stiffness matrices, the STEP policy the adapter allows, dof geometry, the checks that
    refuse a model before any solve.
``backbone_check`` (:mod:`.backbone`)
    with ``[analysis.backbone]``: what it asks of the model (a thickness for ``w_over_h``), before any solve.
``modes`` (:mod:`.modes`)
    the eigen-solve, mode labels, the master modes, the run's model flags.
``step`` (:mod:`.step`)
    the STEP force (or tangent) evaluations: targeted per master, and the full plan when asked.
``evaluators`` (:mod:`.evaluate`, :mod:`.methods`, :mod:`.master`, :mod:`.context`)
    NF/DNF, MD, SMD and the diagnostics of every master mode, with the full-order linear algebra
    built once, on first use.
``backbone`` (:mod:`.backbone`)
    with ``[analysis.backbone]``: the DPIM of every master mode to order N and its backbone curve.
``output_mesh`` (:mod:`.output_mesh`)
    the adapter's mesh for the field files, when the run writes them (:mod:`stepnf.fields`).
``results`` (:mod:`.results`)
    the spectrum, counts, arrays and run flags gathered into a :class:`stepnf.results.RunResult`.

A model given in modal coordinates (:class:`stepnf.modal_model.ModalModel`) runs the short
sequence of :mod:`.modal_coordinates`. A new stage is a module with one ``stage(state)`` function
that reads fields of the state and writes others, added to the sequence in :mod:`stepnf.pipeline`.
"""
