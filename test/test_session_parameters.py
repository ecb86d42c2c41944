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


def test_schemes_get_their_thesis_plant_settings_before_user_overrides():
    """The chapter 6 schemes' sessions set what the thesis runs need (registry
    PLANT_OVERRIDES): K_s = 300, J_m = 1 for singular perturbation; for the robust scheme
    a torque-rate limit its boundary layer survives; a user's -p still wins."""
    def plant(scheme, *overrides):
        cfg = SessionConfig(scheme=scheme, overrides=list(overrides))
        return session_parameters(cfg, Path("x.mcap"))["plant"]

    sp = plant("fjr_singular_perturbation")
    assert sp["scenario"] == "flexible_joint_surface"
    assert sp["joint_stiffness"] == [300.0, 300.0] and sp["motor_inertia"] == [1.0, 1.0]
    assert plant("fjr_robust_adaptive")["effort_rate_limit"] == 100000.0
    assert plant("fjr_robust_adaptive", "plant.effort_rate_limit=1000.0")["effort_rate_limit"] == 1000.0
    assert "effort_rate_limit" not in plant("adaptive_impedance") or \
        plant("adaptive_impedance")["effort_rate_limit"] == 1000.0
