"""Plant + controller + recorder over ROS in lockstep: the MCAP gives the offline numbers."""

import numpy as np
import pytest
from lockstep_replay import as_read
from ros_probe import next_domain

from cr_control.analysis.analyze import load_session, metrics
from cr_control.offline import run_scheme
from cr_control.tools.session import Session, SessionConfig

pytestmark = pytest.mark.ros   # every test here starts ROS (conftest.py)

DURATION = 10.0


@pytest.fixture(scope="module", params=[False, True], ids=["processes", "composed"])
def lockstep_session(request, tmp_path_factory):
    out = tmp_path_factory.mktemp("sessions")
    cfg = SessionConfig(scheme="adaptive_impedance", duration=DURATION, mode="lockstep",
                        composed=request.param, out=out, domain_id=next_domain(), name="run")
    result = Session(cfg, progress=lambda _: None).run()
    return load_session(result.mcap)


@pytest.fixture(scope="module")
def offline():
    return run_scheme("adaptive_impedance", DURATION)


def test_every_cycle_recorded(lockstep_session):
    s = lockstep_session
    n = int(DURATION * 1000)
    assert len(s.status["stamp"]) == n and len(s.reference["stamp"]) == n
    assert len(s.joint_commands.time) == n and len(s.joint_states.time) == n
    assert np.allclose(np.diff(s.status["stamp"]), 1e-3, atol=1e-9)
    assert "plant" in s.parameters and "adaptive_impedance" in s.parameters


def test_lockstep_reproduces_the_offline_loop(lockstep_session, offline):
    """Same plant, same controller, same held-command convention, the wrench the node read
    (lockstep_replay): same trajectory."""
    s = lockstep_session
    n = int(DURATION * 1000)
    reference = as_read(s.status, 1000.0, n, lambda ages: offline if ages is None else
                        run_scheme("adaptive_impedance", DURATION, wrench_ages=ages))
    for field in ("e_x", "e_y", "f_x", "f_y", "tau_1", "tau_2", "c_hat_x", "B_hat_22"):
        assert np.abs(s.status[field] - reference.column(field)).max() < 1e-6, field
    assert np.abs(s.joint_commands.effort - reference.command).max() < 1e-6


def test_metrics_from_the_recording(lockstep_session):
    m = metrics(lockstep_session)
    assert m["pos_err_rms_last_half_m"] < 0.0135          # as offline: 12.6 mm
    assert m["f_err_x_min_N"] > -3.0 and m["loop_fresh_share"] == 1.0
    assert m["tau_peak_joint1_Nm"] < 6.0


@pytest.mark.parametrize("scheme,fields", [
    ("robust_adaptive_impedance", ("e_x", "e_y", "s_x", "s_y", "z_x", "d", "tau_1")),
    ("nn_adaptive_impedance", ("e_x", "s_y", "M_r_hat_norm", "C_r_hat_norm", "G_r_norm", "tau_2")),
])
def test_chapter3_schemes_in_lockstep_match_offline(scheme, fields, tmp_path):
    """The robust and network schemes over ROS (3 s lockstep) give the offline numbers."""
    cfg = SessionConfig(scheme=scheme, duration=3.0, mode="lockstep", out=tmp_path,
                        domain_id=next_domain(), name="run")
    s = load_session(Session(cfg, progress=lambda _: None).run().mcap)
    reference = as_read(s.status, 1000.0, 3000,
                        lambda ages: run_scheme(scheme, 3.0, wrench_ages=ages))
    assert len(s.status["stamp"]) == 3000
    for field in fields:
        assert np.abs(s.status[field] - reference.column(field)).max() < 1e-6, field
