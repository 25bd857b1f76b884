"""``stepnf.open(path)``: a results file written by a run, read back into a :class:`~stepnf.api.view.RunView`.

The file holds the run's JSON document and its arrays (:func:`stepnf.io.results.read_hdf5`); the view
gives the same numbers as the run that wrote it. A file that is missing, a folder, not a stepnf run
file, damaged or edited into a malformed document raises :class:`~stepnf.errors.InputFileError` (a
:class:`~stepnf.errors.SceneError`) with the message ``stepnf show`` prints (:mod:`stepnf.cli.show`).
The DPIM parametrisations are not stored: :meth:`~stepnf.api.view.RunView.plot_backbone` of a stored
run draws the reported backbone points.
"""
from __future__ import annotations

import os

from stepnf.api.view import RunView
from stepnf.cli.show import result_from_document, stored_table
from stepnf.errors import InputFileError, StoreError
from stepnf.io.results import read_hdf5


def open_run(path: str | os.PathLike[str]) -> RunView:
    """The run stored in ``path`` (module docstring). ``stepnf.open`` is this function."""
    table = stored_table(path)  # every check of `stepnf show`, with its messages
    try:
        doc = read_hdf5(path)
    except StoreError as exc:  # the file changed since (another process rewrote it)
        raise InputFileError.of(path, exc) from exc
    arrays = doc.pop("arrays")
    result = result_from_document(doc)
    result.arrays = arrays
    result.hdf5_path = str(path)
    return RunView(doc, result, table=table)
