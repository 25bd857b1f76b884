"""What stepnf writes and reads back: the results of a run (JSON document and HDF5 file, :mod:`.results`),
the fields for ParaView (:mod:`.fields`), the one atomic writer of every file (:mod:`.atomic`) and the
canonical JSON text of stored keys (:mod:`.canonical`)."""
