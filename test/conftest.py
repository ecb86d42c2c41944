"""Every ROS test is isolated: localhost-only discovery and its own domain id."""

import os

import pytest
from ros_probe import next_domain

from cr_control.core.ros_env import FIRST_DOMAIN, isolated_env

# Tests that call rclpy.init in this process inherit these.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", str(FIRST_DOMAIN + os.getpid() % 50))
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def ros_env() -> dict[str, str]:
    """Environment for subprocesses of one test: localhost discovery, a fresh domain id."""
    return isolated_env(domain_id=next_domain())
