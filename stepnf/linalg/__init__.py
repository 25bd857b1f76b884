"""Linear algebra on the model's sparse K and M: direct factorisations with fill-reducing orderings
(:mod:`.factorization`), factorisations of ``K - sigma M`` for successive shifts (:mod:`.shifted`), deflated
shifted solves (:mod:`.deflation`), products of one sparse matrix with blocks (:mod:`.block_product`), and the
modal analysis ``K phi = w^2 M phi`` (:mod:`.modal_analysis`, extended batch by batch in :mod:`.eigen_extension`)."""
