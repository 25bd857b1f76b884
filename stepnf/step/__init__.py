"""STEP (Muravyov and Rizzi 2003): the quadratic and cubic stiffness terms from prescribed displacements
(:mod:`.procedure`), the one path every force evaluation takes from a stage to an adapter (batching,
checking, caching: :mod:`.forces`), and the checkpoints that let a killed run resume without redoing
solver work (:mod:`.checkpoint`)."""
