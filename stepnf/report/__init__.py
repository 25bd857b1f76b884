"""What a person reads: the printed table (:mod:`.table`, :mod:`.backbone_table`), the figures (mode shapes
(:mod:`.mode_shapes`), backbones (:mod:`.backbone_plot`), the paper's Figs. 2-3 (:mod:`.curves`) and 4
(:mod:`.fig4`)) on one matplotlib set-up (:mod:`.figures`)."""
