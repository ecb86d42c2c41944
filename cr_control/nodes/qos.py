"""QoS profiles of the topic contract (topics.py), shared by every node."""

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from cr_control.core import topics

#: The 1 kHz loop topics: RELIABLE, KEEP_LAST topics.QOS_DEPTH.
CONTROL_QOS = QoSProfile(depth=topics.QOS_DEPTH, reliability=ReliabilityPolicy.RELIABLE)

#: Publishers of the loop topics: the same, but a deep writer history. A RELIABLE writer
#: keeps only its last ``depth`` samples for readers that have not acknowledged them; a
#: recorder busy for a few tens of milliseconds while a lockstep loop runs at several kHz
#: lost hundreds of messages per topic with 10. Readers keep depth 10 (a controller that
#: fell behind should not work through a backlog of stale states); matching is unaffected.
PUBLISH_QOS = QoSProfile(depth=topics.PUBLISH_DEPTH, reliability=ReliabilityPolicy.RELIABLE)

#: A controller's /joint_states: the loop's QoS with a deeper reader history. Its plant's
#: states must survive a flood from a second publisher (a flood of 50 000 states as fast as
#: rclpy sends them overwrote them in a history of 10, and the plant's watchdog stopped it);
#: the node takes what is queued in one wake-up and answers only the newest state of its
#: plant, so a deep history is no backlog of stale states.
STATE_QOS = QoSProfile(depth=topics.STATE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)

#: The recorder's ready flag: latched, so a plant that starts later still sees it.
READY_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)

#: Targets (~/target_pose, ~/target_wrench): the latest one counts, as with any command
#: stream; RELIABLE so a single target sent once is not lost.
TARGET_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
