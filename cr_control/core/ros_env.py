"""Environment for processes that start ROS on these machines (DESIGN.md, "Network rule").

Fast DDS multicasts discovery off the machine by default; every process we start runs
with localhost-only discovery and a domain id of its own so parallel runs never meet.
"""

from __future__ import annotations

import os

#: Domain ids handed out automatically lie in [FIRST_DOMAIN, FIRST_DOMAIN + DOMAIN_SPAN);
#: the tests use 51..100 so a session and a test run on one machine never meet.
#: Fast DDS maps domain ids above ~101 onto ports outside the usual Linux range.
FIRST_DOMAIN = 1
DOMAIN_SPAN = 50


def free_domain_id(seed: int | None = None) -> int:
    """A domain id unlikely to be in use by another run on this machine (pid-based)."""
    seed = os.getpid() if seed is None else seed
    return FIRST_DOMAIN + seed % DOMAIN_SPAN


def isolated_env(domain_id: int | None = None, base: dict[str, str] | None = None) -> dict[str, str]:
    """A copy of ``base`` (default: os.environ) with localhost discovery and a domain id.

    A domain id or discovery range already set in ``base`` is kept (users can override).
    """
    env = dict(os.environ if base is None else base)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(domain_id)
    else:
        env.setdefault("ROS_DOMAIN_ID", str(free_domain_id()))
    return env


def isolate_this_process(domain_id: int | None = None) -> None:
    """Apply :func:`isolated_env` to this process before it calls ``rclpy.init``."""
    os.environ.update(isolated_env(domain_id))
