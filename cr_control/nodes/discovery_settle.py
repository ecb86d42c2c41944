"""How long a real-time controller waits, once its DDS participant exists, before it joins
the loop (no process on the domain may stall the loop).

Why (Fast DDS 2.14, the middleware of rmw_fastrtps in Jazzy; measured on this project's
2-core VM, 2026-11-26): the first message a participant sends to another participant's
shared-memory port opens that port, and opening runs a health check
(``SharedMemGlobal::Port::healthy_check``) while the sender holds its participant's send
mutex. The check fails when the port's listener is idle and was verified moments before
by a watchdog (every ``healthy_check_timeout_ms``, 1 s by default, in the owner's
process); the sender then sleeps ``healthy_check_timeout_ms / 3`` = 333 ms, by the owner's
setting, and checks again. Every other send of that participant waits behind it: the
controller's commands, the plant's states. A port opened within a second of its creation
passes at once; a port opened late is a risk (system-wide traces of every sleep of 300 ms
or more, 23 fuzz sessions: the loop's two processes slept 333 ms in such a check 12 times).

Opens come late because a participant already on the domain is discovered only at its
next periodic announcement (every 3 s by default), not when the newcomer announces itself:
the plant and the controller opened the ports of a process started ~1 s before them (the
fuzz's node; likewise rviz or a driver started earlier) a median 2.8 s (at most 3.7 s)
after they were created, whether they ran at nice -10 or not, with or without this
package's profile, and with an announcement period of their own of 0.25 s. The controller
was then in the loop: 334-670 ms stalls, 3 safe stops in about 200 ``cr_fuzz`` sessions
(one in a baseline with nothing sent; the controller's discovery thread was traced
sleeping 333 ms exactly when its commands stopped).

So a real-time controller subscribes to /joint_states only :func:`settle_s` after it was
created: by then it has heard every participant that was on the domain before it, has
opened their ports, and has paid any 333 ms check before it commands anything. Our plant
waits for that subscription before its loop starts (a robot's driver keeps to its own
command timeout meanwhile). Lockstep never waits: there a stall only slows the run.

Participants that join later are the other half: our nodes announce themselves every
0.25 s (their Fast DDS profile, fastdds_profile.xml), so they send to a newcomer within
~0.6 s of its start, while its ports are still fresh (with the default 3 s: up to 3.1 s
after, in the loop; three plain nodes that joined and stayed gave a 632 ms stall in 1 of 3
sessions).
"""

from __future__ import annotations

from cr_control.core.ros_env import env_number

#: Environment variable: the wait in seconds (0: none).
SETTLE_VARIABLE = "CR_CONTROL_DISCOVERY_SETTLE_S"
#: Fast DDS's default announcement period is 3 s; the latest late open seen came 3.7 s after
#: the opener's participant was made (40 sessions, /proc/<pid>/maps sampled every 50 ms).
DEFAULT_SETTLE_S = 4.0
#: A longer wait is a typo, not a setting (s).
MAX_SETTLE_S = 60.0


def settle_s(env: dict[str, str] | None = None) -> float:
    """The wait asked for by SETTLE_VARIABLE of ``env`` (default: os.environ), in s:
    DEFAULT_SETTLE_S when unset or unreadable, else clipped to [0, MAX_SETTLE_S]."""
    return env_number(SETTLE_VARIABLE, DEFAULT_SETTLE_S, 0.0, MAX_SETTLE_S, env=env)


__all__ = ["DEFAULT_SETTLE_S", "MAX_SETTLE_S", "SETTLE_VARIABLE", "settle_s"]
