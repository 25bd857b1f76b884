"""``stepnf verify``: the DPIM backbones against periodic orbits of the full model (:mod:`.command`),
computed by shooting (:mod:`.periodic`) with an energy-conserving integrator (:mod:`.integrate`) or, for
stiff models, Gauss-Legendre collocation (:mod:`.collocation`)."""
