"""~/zero_ft over ROS: the adaptive_impedance executable on the Panda's profile
(its wrist sensor at panda_link8, zeroing at start off) answers std_srvs/Trigger:

- refused before any wrench ("no wrench ... yet");
- a wrench naming another frame than sensor_frame is a sensor fault: still "no wrench";
- after a wrench in panda_link8 and a state at rest (the Panda held at home, out of
  contact, the simulated sensor's noise-free reading): accepted ("zeroing: averaging ...");
- asked again at once: refused, a zeroing is under way.
"""

import sys
import time
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy
from robot_data import needs_erd
from ros_probe import RosProbe, start_node, stop_node
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from cr_control import robots
from cr_control.core import topics
from cr_control.core.paths import config_file
from cr_sim.plants.registry import make_plant

pytestmark = [pytest.mark.ros, needs_erd]
QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
SERVICE = "/adaptive_impedance/zero_ft"


def test_zero_ft_service(ros_env):
    r = robots.robot("panda_ft")
    values = {k: v for k, v in robots.plant_values(r).items() if k != "scenario"}
    plant = make_plant("urdf_surface", {**values, "surface": "none", "ft_noise_std": [0.0, 0.0]})
    plant.step(plant.gravity_torque(np.array(r.home)), 1e-9)          # held: at rest
    m = plant.measurement()
    probe = RosProbe(int(ros_env["ROS_DOMAIN_ID"]), name="zero_ft_probe")
    executable = Path(sys.executable).with_name("adaptive_impedance")
    controller = start_node([str(executable)], ros_env, "--params-file",
                            str(config_file("robots/panda_ft/adaptive_impedance.yaml")),
                            "-p", "zero_ft_at_start:=false", "-p", "state_source:=/zero_ft_probe")
    try:
        node = probe.node
        wrench_pub = node.create_publisher(WrenchStamped, topics.WRENCH, QOS)
        state_pub = node.create_publisher(JointState, topics.JOINT_STATES, QOS)
        answer = probe.call(Trigger, SERVICE, Trigger.Request(), timeout=90)
        assert not answer.success and answer.message.startswith("no wrench on ")

        def send(frame: str, stamp: int) -> None:
            w = WrenchStamped()
            w.header.stamp.sec, w.header.stamp.nanosec = 0, stamp
            w.header.frame_id = frame
            w.wrench.force.x, w.wrench.force.y, w.wrench.force.z = (float(x) for x in m.force)
            w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z = (float(x) for x in m.torque)
            s = JointState(name=list(plant.joint_names), position=[float(x) for x in m.position],
                           velocity=[0.0] * len(m.position), effort=[0.0] * len(m.position))
            s.header.stamp = w.header.stamp
            assert probe.spin_until(lambda: wrench_pub.get_subscription_count() > 0
                                    and state_pub.get_subscription_count() > 0, 30)
            wrench_pub.publish(w)
            time.sleep(0.05)
            state_pub.publish(s)
            probe.spin_until(lambda: False, 0.3)

        send("panda_link0", 1_000_000)           # the wrong frame: a sensor fault
        answer = probe.call(Trigger, SERVICE, Trigger.Request())
        assert not answer.success and answer.message.startswith("no wrench on "), answer.message
        send("panda_link8", 2_000_000)
        answer = probe.call(Trigger, SERVICE, Trigger.Request())
        assert answer.success and answer.message.startswith("zeroing: averaging"), answer.message
        answer = probe.call(Trigger, SERVICE, Trigger.Request())
        assert (not answer.success) and answer.message == "a zeroing is already under way"
    finally:
        code, out = stop_node(controller)
        probe.close()
    assert code == 0, out[-3000:]
    assert "not sensor_frame 'panda_link8'" in out, out[-3000:]
