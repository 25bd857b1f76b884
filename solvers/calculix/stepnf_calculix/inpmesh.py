"""Reading a user's mesh from an Abaqus/CalculiX ``.inp`` file (the ``mesh`` key).

Only the mesh and its named sets are taken: every ``*NODE`` line, every
``*ELEMENT`` block of a solid element type (``C3D*``), and the ``*NSET`` and
``*ELSET`` sets (for ``[[model.boundary]] set = "..."``: an ``*ELSET`` names
the nodes of its elements; for ``[model.materials.<set>]``: its elements);
materials, sections, boundary conditions and steps in the file are ignored
(stepnf writes its own from the scene's materials, :mod:`.sections`; a whole
model is read with ``deck =`` instead, :mod:`.userdeck`). ``*INCLUDE`` is followed (relative to the file's folder).
Continuation lines of ``*ELEMENT`` (a line ending with a comma) are joined.
Nodes that no element uses are dropped (they would carry no stiffness).
"""
from __future__ import annotations

from pathlib import Path

from stepnf.errors import MeshError

from .inpfile import InpMesh, InpModel, inp_lines, keyword_blocks

__all__ = ["read_inp_mesh", "InpMesh"]


def read_inp_mesh(path: str | Path) -> InpMesh:
    """Read the solid mesh of ``path``; raise :class:`~stepnf.errors.MeshError` (a ``ValueError``)
    naming the file, the line, or the element or node (the file's ids) at fault.

    The nodes and elements found are checked by
    :func:`stepnf.geometry.checks.check_volume_mesh` (NaN coordinates, undefined
    nodes, flat meshes, coincident nodes, degenerate, tangled or overlapping elements).
    """
    path = Path(path)
    if not path.is_file():
        raise MeshError(path, f"mesh file {path} does not exist")
    model = InpModel(path)
    for block in keyword_blocks(inp_lines(path)):
        model.add(block)
    return model.mesh()
