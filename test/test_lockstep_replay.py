"""The offline loop replays the wrench a controller node read (``wrench_ages``), so a lockstep
session that read an older wrench at a state is compared with the run that did the same
(lockstep_replay.py); the node reports that age in its status (``wrench_age_ms``,
test_controller_node_input.py)."""

import numpy as np
from lockstep_replay import wrench_ages

from cr_control.offline import run_scheme

SCHEME, DURATION = "adaptive_impedance", 1.0


def law_columns(run) -> np.ndarray:
    """The status without the cycle's compute time (wall time, never the same twice)."""
    return np.array([run.column(f) for f in run.status_fields[1:] if f != "compute_time_us"]).T


def test_no_ages_is_the_plain_run_and_an_older_wrench_is_read_where_asked():
    plain = run_scheme(SCHEME, DURATION)
    steps = len(plain.time)
    same = run_scheme(SCHEME, DURATION, wrench_ages=np.zeros(steps, dtype=int))
    assert np.array_equal(law_columns(same), law_columns(plain), equal_nan=True)
    assert np.array_equal(same.command, plain.command)
    ages = np.zeros(steps, dtype=int)
    ages[500], ages[501] = 1, 2                 # a wrench lost at 500, resent after 501
    late = run_scheme(SCHEME, DURATION, wrench_ages=ages)
    f_x = plain.column("f_x")
    assert np.array_equal(law_columns(late)[:500], law_columns(plain)[:500], equal_nan=True)
    assert late.column("f_x")[500] == f_x[499] and late.column("f_x")[501] == f_x[499]
    assert f_x[500] != f_x[499]
    assert np.abs(late.command[500:] - plain.command[500:]).max() > 0.0   # the runs part


def test_ages_from_a_recorded_status():
    stamps = np.arange(1, 6) * 1e-3                    # steps 1..5 recorded, step 0 missing
    status = {"stamp": stamps, "wrench_age_ms": np.array([0.0, 1.0, 2.0, 0.0, -1.0])}
    np.testing.assert_array_equal(wrench_ages(status, 1000.0, 6), [0, 0, 1, 2, 0, -1])
    assert wrench_ages({"stamp": stamps, "wrench_age_ms": np.zeros(5)}, 1000.0, 6) is None
    assert wrench_ages({"stamp": stamps}, 1000.0, 6) is None          # a status without it
    np.testing.assert_array_equal(                                   # 500 Hz: periods of 2 ms
        wrench_ages({"stamp": stamps[:2] * 2, "wrench_age_ms": np.array([2.0, 4.0])}, 500.0, 3),
        [0, 1, 2])
