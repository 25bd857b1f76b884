"""The direct parametrisation of the single-mode invariant manifold (DPIM) to arbitrary order
(:mod:`.parametrisation`), with its linear solves (:mod:`.solves`), the nonlinear terms of each order from the
black box (:mod:`.nonlinear_terms`, on the polarised terms of :mod:`.polarisation`; the autonomous
right-hand sides of the homological equations, not an external force), the backbone curve and its validity
(:mod:`.backbone`) and what a run reports of it (:mod:`.backbone_report`)."""
