"""cr_identify_tool on a robot: the poses and the least squares through the topics of a
running controller, here a lockstep Panda session (the simulated wrist sensor: 0.7 kg tool,
COM 6 cm out, a few newtons of bias, 0.2 N of noise) with the table out of reach.

Measured: 0.6998 kg (-0.03 %), COM 0.12 mm off, bias within 0.01 N; the issue asks 2 % and
5 mm.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys

import numpy as np
import pytest
from robot_data import needs_erd

from cr_control import robots
from cr_control.core import ros_yaml

pytestmark = [pytest.mark.ros, needs_erd]


def test_identification_through_the_topics(tmp_path, ros_env):
    env = {k: v for k, v in ros_env.items() if k != "ROS_DOMAIN_ID"}   # the session takes one
    # 600 s: longer than any start of the tool, however loaded the machine (lockstep runs ~3x
    # real time; the tool needs ~16 s of poses); stopped with Ctrl-C once the tool is done
    session = subprocess.Popen(
        [sys.executable, "-m", "cr_control.tools.session", "--robot", "panda_ft", "--mode",
         "lockstep", "--duration", "600", "--no-analysis", "--no-record", "--out", str(tmp_path),
         "-p", "plant.surface=none", "-p", "adaptive_impedance.approach_speed=0.0"], env=env,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True)
    try:
        first = session.stdout.readline()
        domain = re.search(r"ROS_DOMAIN_ID=(\d+)", first)
        assert domain, first
        out = tmp_path / "tool.yaml"
        proc = subprocess.run(
            [sys.executable, "-m", "cr_control.tools.identify_tool", "--controller",
             "/adaptive_impedance", "--domain-id", domain[1], "--settle", "1.5", "--average",
             "0.5", "--timeout", "60", "--out", str(out)],
            env=env, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        print(proc.stdout)
    finally:
        session.send_signal(signal.SIGINT)       # cr_session stops its processes
        session.communicate(timeout=60)
    values = ros_yaml.load(out.read_text())["adaptive_impedance"]["ros__parameters"]
    truth = robots.SENSOR
    assert values["sensor_frame"] == "panda_link8"
    assert values["tool_mass"] == pytest.approx(truth["tool_mass"], rel=0.02)
    assert np.linalg.norm(np.array(values["tool_com"]) - truth["tool_com"]) < 0.005
    assert np.abs(np.array(values["ft_bias"][:3]) - truth["ft_bias"][:3]).max() < 0.1


def test_an_absent_controller_is_one_line(ros_env):
    proc = subprocess.run([sys.executable, "-m", "cr_control.tools.identify_tool", "--controller",
                           "/nobody", "--timeout", "0.5"], env=ros_env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.startswith("cr_identify_tool: no node /nobody")
    assert "Traceback" not in proc.stderr
