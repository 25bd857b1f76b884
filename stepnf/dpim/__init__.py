"""The direct parametrisation of the single-mode invariant manifold (DPIM) to arbitrary order
(:mod:`.parametrisation`), with its linear solves (:mod:`.solves`), its nonlinear forcing from the black box
(:mod:`.forcing`, on the polarised terms of :mod:`.polarisation`), the backbone curve and its validity
(:mod:`.backbone`) and what a run reports of it (:mod:`.backbone_report`)."""
