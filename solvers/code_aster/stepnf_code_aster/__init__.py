"""The ``code_aster`` solver adapter: code_aster driven as a black box through command templates.

Internal forces: ONE code_aster run per batch of displacement fields. stepnf
writes the mesh and the fields into ``model.med`` (field ``U``: zero at time
0, field i at time i), renders ``forces.comm`` (``LIRE_RESU`` of the fields,
``AFFE_CHAR_CINE(EVOL_IMPO=...)`` imposing every dof of every node, one
``STAT_NON_LINE`` with ``DEFORMATION="GROT_GDEP"``, ``RELATION="ELAS"``,
``CALC_CHAMP(FORCE="FORC_NODA")``, ``IMPR_RESU`` to MED) and
``forces.export``, runs the command (default ``run_aster ${export}``) and reads
``FORC_NODA`` back from the MED result with h5py (float64: no loss of
digits). K and M: ``matrices.comm`` (``ASSEMBLAGE`` of ``RIGI_MECA`` and
``MASS_MECA``, exported with ``EXTR_MATR(sparse=True)`` and the dof map to an
``.npz``; code_aster >= 16).

``force_route = "calcul"`` (default ``"stat_non_line"``) renders ``forces_calcul.comm`` for
the force job instead: per field, ``CALCUL(OPTION=("FORC_INTE_ELEM",))`` at ``DEPL`` = 0,
``INCR_DEPL`` = the field, zero ``SIGM`` and ``VARI``, ``COMPORTEMENT`` ``ELAS``/``GROT_GDEP``
(one element loop, no Newton iteration and no matrix factorisation, the route of the
ROM_for_geomNL scripts), ``EXTR_TABLE`` of the elementary vectors, ``ASSE_VECTEUR``, and the
fields gathered by ``CREA_RESU`` as ``FORC_NODA`` at times 1..n, so the same MED reader
applies. Both routes' keywords are checked against code_aster 15's command catalogue
(``tests/solvers/code_aster/test_code_aster_catalogue.py``); the CALCUL route has never been run in code_aster by
stepnf (no code_aster here), so the default stays the STAT_NON_LINE route.

Scene keys (``[model]``)::

    solver = "code_aster"
    element = "hex20"                 # generated shells: HEXA20
    [model.geometry]                  # same keys as the fenicsx and calculix adapters
    shape = "spherical_cap"
    a = 0.15
    R = 1.5                           # "inf": flat plate
    h = 0.003
    [model.material]
    E = 1.04e11
    nu = 0.3
    rho = 4400.0

or ``mesh = "part.med"`` (a user's MED volume mesh; ``mesh_name`` picks one
of several meshes), with ``[model.material]`` isotropic or orthotropic (``E1`` ...
``G23``, ``rho``, optional ``axes``) and ``[model.materials.<group>]`` for named
groups of volume cells of the MED file (:mod:`stepnf.plugin.materials`): written as
``${materials}`` (``DEFI_MATERIAU`` ``ELAS``/``ELAS_ORTH``, ``AFFE_MATERIAU``) and
``${cara_elem}`` (``AFFE_CARA_ELEM`` ``MASSIF`` ``ANGL_REP``) of the templates. Run keys: ``command`` (e.g. ``"docker run --rm -v
${workdir}:${workdir} simvia/code_aster run_aster ${export}"``), ``templates``
(a folder whose ``forces.comm``, ``forces.export``, ``matrices.comm`` or
``matrices.export``, ``forces_calcul.comm`` replace the shipped ones), ``force_route``, ``version``, ``ncpus``,
``memory_mb`` (``.export`` parameters), ``timeout``, ``workdir``, ``keep``,
``parallel_runs`` (code_aster runs at a time, each on a share of a batch).
``command`` and ``templates`` run what the scene names (the command files are
Python): honoured only when the user allows programs named by scenes
(``--allow-programs`` or ``STEPNF_ALLOW_PROGRAMS=1``, :mod:`stepnf.runtime.programs`),
the command then printed before it first runs; a relative program in
``command`` is the scene folder's; the default ``run_aster`` is looked up in
the absolute folders of PATH only. The shipped command files hold names and
paths as Python string literals (``${mesh_name_py}``, ``${matrices_file_py}``:
``repr``); ``mesh_name`` (or a MED file's own mesh name, also ``${mesh_name}``
as is, for a user's template) refuses quotes, backslashes and control
characters, ``version`` anything but a plain version name, and the work
folders' parent (``workdir``, else the temporary folder, TMPDIR) spaces,
quotes, backslashes and control characters: the ``.export`` file names the
files by their paths and splits its lines at spaces.

Shells (:mod:`.shell`): ``element = "dkt"`` or ``"coque_3d"`` with ``mesh = "<MED mid-surface>"`` and
``thickness``: six dofs a node (``ux uy uz rx ry rz``), ``forces_shell.comm`` (one ``STAT_NON_LINE`` per
field from the reference state, ``GROT_GDEP``, forces and moments) and ``matrices_shell.comm``;
catalogue-checked, never run here (``solvers/code_aster/README.md``: what code_aster says of DKT under large
displacements).

MED helpers (:mod:`.med`): :func:`read_nodal_steps`, :func:`list_fields`,
:func:`write_med`, :func:`add_nodal_field`.
"""
from __future__ import annotations

from .adapter import CodeAsterAdapter, shipped_template, triplets_to_matrix
from .shell import CodeAsterShellAdapter  # registers itself as CodeAsterAdapter.shell_class
from .med import (MedError, NodalStep, add_nodal_field, list_fields, read_mesh_nodes, read_nodal_field,
                  read_nodal_steps, read_profile, write_med)

__all__ = ["CodeAsterAdapter", "CodeAsterShellAdapter", "shipped_template", "triplets_to_matrix", "MedError", "NodalStep",
           "add_nodal_field", "list_fields", "read_mesh_nodes", "read_nodal_field", "read_nodal_steps",
           "read_profile", "write_med"]
