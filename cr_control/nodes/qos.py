"""QoS profiles of the topic contract (topics.py), shared by every node."""

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from cr_control.core import topics

#: The 1 kHz loop topics: RELIABLE, KEEP_LAST topics.QOS_DEPTH.
CONTROL_QOS = QoSProfile(depth=topics.QOS_DEPTH, reliability=ReliabilityPolicy.RELIABLE)

#: The recorder's ready flag: latched, so a plant that starts later still sees it.
READY_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
