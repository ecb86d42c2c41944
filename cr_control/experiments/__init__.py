"""Experiments on many offline runs: sweeps (``cr_sweep``), gain tuning (``cr_tune``) and the
thesis reproduction (``cr_reproduce``), run on Ray (Ray Tune for the tuning).

Modules by responsibility: :mod:`.spec` (the SPEC file, checked against the schemes' and
plants' own :class:`~cr_control.core.parameters.Param` declarations), :mod:`.points` (grid
and seeded random points), :mod:`.evaluate` (one point: the offline loop and the analysis
metrics of ``cr_analyze``), :mod:`.engine` (Ray, loopback only), :mod:`.store` (finished
points persisted as they finish; resuming), :mod:`.table` (results.csv / results.parquet),
:mod:`.plots`, :mod:`.progress`, and the command-line tools :mod:`.sweep`, :mod:`.tune`,
:mod:`.reproduce`.
"""
