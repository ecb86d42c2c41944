"""cr_identify_tool on a robot: the poses and the least squares through the topics of a
running controller, here a lockstep Panda session (the simulated wrist sensor: 0.7 kg tool,
COM 6 cm out, a few newtons of bias, 0.2 N of noise) with the table out of reach and the
controller asking no force (no approach, desired_force zero: else its start check stops it
at 0.8 s, before the tool's first pose on a loaded machine).

Measured: 0.6998 kg (-0.03 %), COM 0.12 mm off, bias within 0.01 N; the issue asks 2 % and
5 mm.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
from contextlib import contextmanager

import numpy as np
import pytest
from robot_data import needs_erd

from cr_control import robots
from cr_control.core import ros_yaml

pytestmark = [pytest.mark.ros, needs_erd]


#: The controller in free space as the tool asks: no guarded approach, no contact force; its
#: targets go stale after 10 s, not 0.5 s: the tool streams them by its own clock while a
#: lockstep plant runs as fast as the controller answers, so a tool descheduled for 0.4 s on a
#: loaded machine let them go stale mid-pose (the arm then holds, and the pose is missed).
FREE_SPACE = ("-p", "adaptive_impedance.approach_speed=0.0",
              "-p", "adaptive_impedance.desired_force=[0.0,0.0,0.0]",
              "-p", "adaptive_impedance.target_timeout=10.0")


@contextmanager
def free_space_session(tmp_path, env: dict[str, str], *overrides: str):
    """The domain id of a lockstep panda_ft session with the table removed; 600 s: longer
    than any start of the tool, however loaded the machine (lockstep runs ~3x real time; the
    tool needs ~16 s of poses); stopped with Ctrl-C once the tool is done."""
    session = subprocess.Popen(
        [sys.executable, "-m", "cr_control.tools.session", "--robot", "panda_ft", "--mode",
         "lockstep", "--duration", "600", "--no-analysis", "--no-record", "--out", str(tmp_path),
         "-p", "plant.surface=none", *overrides], env=env,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        first = session.stdout.readline()
        domain = re.search(r"ROS_DOMAIN_ID=(\d+)", first)
        assert domain, first
        yield domain[1]
    finally:
        session.send_signal(signal.SIGINT)       # cr_session stops its processes
        try:
            session.communicate(timeout=60)
        except subprocess.TimeoutExpired:        # never left running on its domain
            session.kill()
            session.communicate()
            raise


def identify(domain: str, env: dict[str, str], out) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "cr_control.tools.identify_tool", "--controller",
         "/adaptive_impedance", "--domain-id", domain, "--settle", "1.5", "--average",
         "0.5", "--timeout", "60", "--out", str(out)],
        env=env, capture_output=True, text=True, timeout=300)


def test_identification_through_the_topics(tmp_path, ros_env):
    env = {k: v for k, v in ros_env.items() if k != "ROS_DOMAIN_ID"}   # the session takes one
    out = tmp_path / "tool.yaml"
    with free_space_session(tmp_path, env, *FREE_SPACE) as domain:
        proc = identify(domain, env, out)
    assert proc.returncode == 0, proc.stderr
    print(proc.stdout)
    values = ros_yaml.load(out.read_text())["adaptive_impedance"]["ros__parameters"]
    truth = robots.SENSOR
    assert values["sensor_frame"] == "panda_link8"
    assert values["tool_mass"] == pytest.approx(truth["tool_mass"], rel=0.02)
    assert np.linalg.norm(np.array(values["tool_com"]) - truth["tool_com"]) < 0.005
    assert np.abs(np.array(values["ft_bias"][:3]) - truth["ft_bias"][:3]).max() < 0.1


def test_a_controller_asking_a_contact_force_is_refused(tmp_path, ros_env):
    """The profile's 10 N wiping force in free space pushes the tip off its reference (the
    controller's start check stops it within a second): the tool says so before any pose,
    and nothing is written."""
    env = {k: v for k, v in ros_env.items() if k != "ROS_DOMAIN_ID"}
    out = tmp_path / "tool.yaml"
    with free_space_session(tmp_path, env, *FREE_SPACE[:2]) as domain:
        proc = identify(domain, env, out)
    assert proc.returncode == 2
    assert proc.stderr.startswith("cr_identify_tool: /adaptive_impedance asks a contact force "
                                  "(desired_force [0.0, 0.0, 10.0])"), proc.stderr
    assert len(proc.stderr.splitlines()) == 1 and not out.exists()


def test_an_absent_controller_is_one_line(ros_env):
    proc = subprocess.run([sys.executable, "-m", "cr_control.tools.identify_tool", "--controller",
                           "/nobody", "--timeout", "0.5"], env=ros_env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.startswith("cr_identify_tool: no node /nobody")
    assert "Traceback" not in proc.stderr
