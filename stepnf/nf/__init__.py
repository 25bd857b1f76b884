"""The backbone coefficient T of one master mode: its definition and the method record
(:mod:`.coefficient`), the evaluators NF, DNF, MD and SMD (:mod:`.evaluators`), their first-order
full-order corrections (:mod:`.linearised`), the indicators around them (:mod:`.diagnostics`), whether a
single-mode manifold exists (:mod:`.manifold_checks`) and Gamma, T per squared amplitude in thicknesses
(:mod:`.gamma`). docs/design.md section 1 holds the mathematics."""
