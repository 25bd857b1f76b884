"""STEP (Muravyov and Rizzi 2003): the quadratic and cubic stiffness terms from prescribed displacements
(:mod:`.procedure`; for a force that is not an exact cubic, the cubic fit's truncation measured and
extrapolated: :mod:`.truncation`), the one path every force evaluation takes from a stage to an adapter (batching,
checking, caching: :mod:`.forces`), and the checkpoints that let a killed run resume without redoing
solver work (:mod:`.checkpoint`)."""
