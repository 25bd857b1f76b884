"""The command line: ``stepnf run|modes|show|check|verify|sweep|solvers|curves|fig4`` (:mod:`.main`), the
console script and its memory guard (:mod:`.console`), and the commands that are more than a call
(:mod:`.modes`, :mod:`.check`, :mod:`.show`; ``verify`` lives in :mod:`stepnf.verify`)."""
