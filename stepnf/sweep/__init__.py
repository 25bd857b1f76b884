"""Sweeps: many scenes run on Dask, each finished case stored at once and resumable (:mod:`.dask_sweep`),
in one HDF5 store keyed by the model that computed each case (:mod:`.store`); the scheduler addresses
accepted (:mod:`.dask_address`)."""
