"""The process stepnf runs in: memory limits, signals, MPI's session folder, progress lines, what is safe
to print, work counters (no numerics here, no FE library)."""
