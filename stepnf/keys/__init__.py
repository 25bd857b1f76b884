"""Declared keys and their checks: the one TOML reader and the typed checks with one wording
(:mod:`.checks`), the schema a table declares (:mod:`.schema`: :class:`~.schema.Key`,
:class:`~.schema.Schema`, :class:`~.schema.FromScene`), and the ``[analysis.backbone]`` table
(:mod:`.backbone`). Below every package that declares keys (adapters, geometry, models, the scene)."""
