"""Helpers shared by the test suite: a test file imports from here (or uses a conftest fixture), never from
another test file (tests/env/test_structure.py checks it).

``tests/conftest.py`` puts ``tests/`` on ``sys.path``, so a test imports ``from helpers.systems import
random_system``. Modules:

* :mod:`helpers.paths`: the checkout's folders (REPO, TESTS, EXAMPLES, DATA), for tests at any depth;
* :mod:`helpers.systems`: polynomial systems from a potential (random, the 2-dof and stiff 2-dof systems),
  their batch force and modes, solvers resolved by name;
* :mod:`helpers.scenes`: small polynomial scenes, ``stepnf verify`` run in-process;
* :mod:`helpers.chain`: a chain of masses with cubic springs (a small conservative adapter);
* :mod:`helpers.meshes` and :mod:`helpers.beam`: structured hexahedra, the FE cap's scene tables, the
  slender beam of the FEniCSx tests;
* :mod:`helpers.code_aster`: a fake ``run_aster``, a generated cap, MED files with cell groups;
* :mod:`helpers.fields`: field files read back by VTK;
* :mod:`helpers.hostile` and :mod:`helpers.programs`: the CLI run on hostile input, scenes naming programs;
* :mod:`helpers.plugins`: fake installed plugins (and the slow sweep's);
* :mod:`helpers.mpi`: ``mpirun`` for runs on several processes;
* :mod:`helpers.required`: the tools the set-up installs (tests/required_tools.txt);
* :mod:`helpers.rootfs`: Debian root file systems and the checkout copied into them, for chroot tests.
"""
