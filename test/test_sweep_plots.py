"""The sweep's figures (cr_control/experiments/plots.py) from a results table, without Ray."""

from __future__ import annotations

import math

from cr_control.experiments import plots


def test_an_infinite_metric_is_left_out_not_a_crash(tmp_path):
    """A point whose metric is infinite (a law that ran away within its run) among good ones:
    the figure is drawn without it (before, matplotlib's tick locator raised on the axis)."""
    table = [{"status": "ok", "k": 1.0, "force_rms": 1.0},
             {"status": "ok", "k": 2.0, "force_rms": math.inf},
             {"status": "ok", "k": 3.0, "force_rms": 2.0}]
    [figure] = plots.plot(tmp_path, ["force_rms"], table, ["k"], ["force_rms"], False)
    assert figure.name == "force_rms.png" and figure.stat().st_size > 1000
    grid = [dict(row, c=c) for row in table for c in (0.5, 1.0)]
    (tmp_path / "grid").mkdir()
    assert len(plots.plot(tmp_path / "grid", ["force_rms"], grid, ["k", "c"], ["force_rms"], True)) == 1
