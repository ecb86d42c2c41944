"""What the session runner hands each node (no ROS started)."""

from pathlib import Path

from cr_control.tools.session import REALTIME_DIAGNOSTICS_EVERY, SessionConfig, session_parameters


def _params(**kwargs):
    return session_parameters(SessionConfig(scheme="adaptive_impedance", **kwargs), Path("x.mcap"))


def test_real_time_sessions_decimate_the_diagnostics_lockstep_keeps_every_cycle():
    realtime = _params(mode="realtime")["adaptive_impedance"]["diagnostics_every"]
    assert realtime == REALTIME_DIAGNOSTICS_EVERY > 1
    assert _params(mode="lockstep")["adaptive_impedance"]["diagnostics_every"] == 1
    full = _params(mode="realtime", overrides=["adaptive_impedance.diagnostics_every=1"])
    assert full["adaptive_impedance"]["diagnostics_every"] == 1


def test_plant_mode_and_duration_follow_the_session():
    plant = _params(mode="lockstep", duration=3.0)["plant"]
    assert plant["mode"] == "lockstep" and plant["duration"] == 3.0 and plant["scenario"] == "compliant_plane"
