"""The builders of the report's sections, one module per topic, each over result.json's plain dicts.

:mod:`.provenance` (header and provenance), :mod:`.views` (the per-view table), :mod:`.result` (X in
every form, the prior, the sigmas), :mod:`.methods` (closed forms and offsets), :mod:`.models`
(intrinsics, noise, robot error model), :mod:`.diagnostics` (findings, stages, held-out validation),
:mod:`.verdict` (headline cards) and :mod:`.values` (reading numbers). They return plain values;
:mod:`handeye.report.context` assembles them into the template context.
"""
