"""The ``calculix`` solver adapter: CalculiX ``ccx`` (2.20) driven as a black box through input decks.

Internal forces: one ``ccx`` run per batch of displacement fields, one
``*STEP, NLGEOM`` / ``*STATIC, DIRECT`` step per field in which every dof of
every node is prescribed (``*BOUNDARY``) to the field's *total* displacement,
so each step is independent of the previous ones; ``*NODE PRINT ... RF`` gives
the internal force (sign of ``K u``) with 7 significant digits. K and M: one
``*FREQUENCY, SOLVER=MATRIXSTORAGE`` run (``.sti``, ``.mas``, ``.dof``, 14
digits), read once and cached. Every real number is written with ``%.13e``
(ccx truncates input numbers to 20 characters).

Precision: forces carry 7 significant digits, so STEP's ``G`` and ``H`` are
accurate to about ``5e-7 |K q phi| / |G q^2|`` and ``5e-7 |K q phi| / |H q^3|``
(measured on the kappa = 25 cap, mode (2,0), q = h/2: ``G`` 1e-7, ``h_ppp``
2e-6 relative); f is an exact cubic (St Venant-Kirchhoff), so larger
amplitudes (``relative_amplitude`` 2-4) only gain digits. Sharper:
:meth:`CalculixAdapter.tangent_stiffness` (an NLGEOM step then a
``*STEP, PERTURBATION`` storing the tangent, 14 digits) and
:meth:`CalculixAdapter.sharp_step` (``G(phi, phi)`` and ``h_ppp`` from the
tangents at ``+-q phi``: amplitude-independent to 1e-9).

Scene keys (``[model]``)::

    solver = "calculix"
    element = "hex20"              # 20-node bricks C3D20 (the only choice for generated shells)
    [model.geometry]               # a generated free-edge cap (same keys as the fenicsx adapter)
    shape = "spherical_cap"
    a = 0.15
    R = 1.5                        # "inf": flat plate
    h = 0.003
    n_core = 12                    # optional resolution: n_core, n_ring, n_thick, core
    [model.material]
    E = 1.04e11
    nu = 0.3
    rho = 4400.0

or, instead of ``[model.geometry]``, ``mesh = "part.inp"`` (a user's solid
mesh: ``*NODE`` and ``*ELEMENT`` blocks of C3D* elements, ``*NSET`` and
``*ELSET`` sets, surface elements beside them taken as sets; or a Gmsh
``part.msh``, its physical groups as sets: :mod:`.inpmesh`; the material of ``[model.material]`` applies to every
element but those of the named element sets given their own, isotropic or
orthotropic, :mod:`stepnf.plugin.materials`)::

    [model.material]               # every element not in a set below; isotropic, or
    E1 = 1.3e11                    # orthotropic: E1 E2 E3 nu12 nu13 nu23 G12 G13 G23
    ...
    rho = 1600.0
    axes = [[1, 1, 0], [-1, 1, 0]] # optional: material axes 1 and 2 (*ORIENTATION)
    [model.materials.CORE]         # the elements of the *ELSET CORE
    E = 2.1e11
    nu = 0.3
    rho = 7800.0

(written as one ``*MATERIAL`` per material and one ``*SOLID SECTION`` per
element set, :mod:`.sections`; an element in two of the sets, in none without
``[model.material]``, or a set the mesh lacks is refused naming the key),
or ``deck = "model.inp"`` (a user's whole CalculiX model: nodes,
elements, sets, ``*MATERIAL`` blocks, ``*SOLID SECTION`` s, ``*ORIENTATION`` s
and zero ``*BOUNDARY`` lines kept as written, its ``*STEP`` blocks replaced by
stepnf's; no ``[model.material]``; what stepnf cannot honour is refused with
its line: :mod:`.userdeck`).

Boundary conditions (:mod:`stepnf.plugin.boundary`)::

    [[model.boundary]]
    set = "LEFT"                   # an *NSET (or the nodes of an *ELSET); "edge": a generated cap's rim
    dofs = ["ux", "uy", "uz"]      # optional; default: clamped
    [[model.boundary]]
    box = [[0.0, -1.0, -1.0], [0.0, 1.0, 1.0]]   # or the nodes inside a box

add to a deck's own ``*BOUNDARY`` conditions. The fixed dofs are removed from
the dofs the adapter exposes (K, M, forces, tangents): ccx runs the whole
unconstrained model and the free rows and columns are kept, which is exact
(see :class:`CalculixAdapter`). Optional run keys:
``template = "my_job.inp"`` (a job template with the placeholders
``${mesh_file}``, ``${steps}`` and, if it uses them, ``${E}``, ``${nu}``,
``${rho}`` (one isotropic material), ``${materials}`` (the blocks stepnf
writes: needed for regions or orthotropic constants), ``${title}``; the
shipped ones are ``templates/job.inp`` and ``templates/materials_job.inp``),
``executable = "ccx"`` (a name on PATH or a path, relative to the scene's
folder; honoured only when the user allows programs named by scenes:
``--allow-programs`` or ``STEPNF_ALLOW_PROGRAMS=1``, :mod:`stepnf.runtime.programs`, and
then printed before it first runs), ``timeout = 3600`` (s per run), ``workdir = "runs"``
(parent of the work folders, default the system temp folder), ``keep =
"on_error"`` (or ``"never"``, ``"always"``), ``threads`` (``OMP_NUM_THREADS``),
``parallel_runs`` (ccx processes at a time, each on a share of a batch: ccx
spends its time per step, mostly on one core, so 2 runs on 2 cores nearly
halve the force-evaluation time).
"""
from __future__ import annotations

from .adapter import CalculixAdapter, shipped_template
from .inpmesh import read_inp_mesh
from .userdeck import UserDeck, read_deck

__all__ = ["CalculixAdapter", "shipped_template", "read_inp_mesh", "read_deck", "UserDeck"]
