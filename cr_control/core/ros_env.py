"""Environment for processes that start ROS: discovery on localhost only, a domain each.

Fast DDS multicasts discovery off the machine by default; every process we start runs
with localhost-only discovery and a domain id of its own so parallel runs never meet.

"Of its own" is enforced machine-wide by a lock file per domain id
(``$TMPDIR/cr_control-domains/<id>.lock``, ``flock``-ed): :func:`claim_domain` takes an
id for as long as the process lives (the kernel releases it when the process dies, even
on SIGKILL), :func:`claim_free_domain` takes the first id nobody holds. Sessions hand
out ids in 1..50, tests in 51..100, so a session and a test run never meet either.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import math
import os
import tempfile
from pathlib import Path

#: Domain ids handed out automatically lie in [FIRST_DOMAIN, FIRST_DOMAIN + DOMAIN_SPAN);
#: the tests use 51..100 so a session and a test run on one machine never meet.
#: Fast DDS maps domain ids above ~101 onto ports outside the usual Linux range.
FIRST_DOMAIN = 1
DOMAIN_SPAN = 50
#: Largest ROS_DOMAIN_ID Fast DDS accepts on Linux.
MAX_DOMAIN_ID = 232
#: Where the per-domain lock files live (shared by every user of this machine).
LOCK_DIR = Path(tempfile.gettempdir()) / "cr_control-domains"
#: The Fast DDS profile of our nodes in real time (frequent heartbeats on the loop topics;
#: see the file), and in lockstep (on every writer: the lockstep pacing waits for acks).
NODE_DDS_PROFILE = Path(__file__).with_name("fastdds_profile.xml")
LOCKSTEP_DDS_PROFILE = Path(__file__).with_name("fastdds_profile_lockstep.xml")
#: The profile of a tool that joins a running session for a moment (UDP only: the loop's
#: nodes never send to it through shared memory; see the file).
VISITOR_DDS_PROFILE = Path(__file__).with_name("fastdds_profile_visitor.xml")
#: Where Fast DDS (2.x) looks for a profile: this variable, else this file in the cwd.
DDS_PROFILE_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"
DDS_PROFILE_IN_CWD = "DEFAULT_FASTRTPS_PROFILES.xml"


def env_number(variable: str, default: float, low: float, high: float, *, parse=float,
               invalid: float | None = None, env: dict[str, str] | None = None) -> int | float:
    """The number in ``variable`` of ``env`` (default: os.environ), read by ``parse``
    (``float`` or ``int``) and clamped to [low, high]: ``default`` if unset or blank,
    ``invalid`` (default: ``default``) if it does not parse or is not finite. The loop's
    settings by environment (nice, priority, heap reserve, discovery wait) read this way."""
    text = (os.environ if env is None else env).get(variable, "").strip()
    if not text:
        return default
    try:
        value = parse(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        return default if invalid is None else invalid
    return max(low, min(high, value))


def check_domain_id(value: int | str) -> int:
    """``value`` as a domain id (ValueError saying why if it is not an integer in 0..232)."""
    try:
        domain_id = int(value)
    except (TypeError, ValueError):
        raise ValueError(f"ROS_DOMAIN_ID must be an integer, not {value!r}") from None
    if not 0 <= domain_id <= MAX_DOMAIN_ID:
        raise ValueError(f"ROS_DOMAIN_ID must be in 0..{MAX_DOMAIN_ID}, not {domain_id}")
    return domain_id


def domain_id_arg(text: str) -> int:
    """argparse ``type`` of a ``--domain-id`` option (see :func:`check_domain_id`)."""
    try:
        return check_domain_id(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


class DomainBusyError(RuntimeError):
    """The domain id is held by another process on this machine; the message says which."""


class DomainLock:
    """This process's claim on one ROS domain id (see :func:`claim_domain`).

    Claims are counted within a process: claiming an id this process already holds
    returns the same lock, which is released when every claim has been released.
    """

    def __init__(self, domain_id: int, fd: int):
        self.domain_id = domain_id
        self._fd = fd
        self._claims = 1

    @property
    def held(self) -> bool:
        """True until the last claim is released."""
        return self._claims > 0

    def fileno(self) -> int:
        """The lock file's descriptor: a child process that inherits it holds the lock too."""
        return self._fd

    def release(self) -> None:
        """Give one claim back; the id is free for others once the last one is."""
        if self._claims == 0:
            return
        self._claims -= 1
        if self._claims == 0:
            _held.pop(self.domain_id, None)
            os.close(self._fd)  # closing the descriptor drops the flock

    def __enter__(self) -> DomainLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


#: Domain id -> this process's lock on it.
_held: dict[int, DomainLock] = {}


def _lock_path(domain_id: int) -> Path:
    LOCK_DIR.mkdir(mode=0o777, parents=True, exist_ok=True)
    with contextlib.suppress(OSError):  # fails if another user made it: theirs to set
        LOCK_DIR.chmod(0o1777)  # sticky, world-writable: other users may claim ids too
    return LOCK_DIR / f"{domain_id}.lock"


def _holder(path: Path) -> str:
    """Who holds a lock file, as its holder wrote it ("" if unknown)."""
    try:
        return path.read_text().strip()
    except OSError:
        return ""


def claim_domain(domain_id: int) -> DomainLock:
    """Hold ``domain_id`` for this process's lifetime (or until released).

    Raises :class:`DomainBusyError` naming the holder if another process holds it.
    """
    if domain_id in _held:
        lock = _held[domain_id]
        lock._claims += 1
        return lock
    path = _lock_path(domain_id)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    with contextlib.suppress(OSError):
        os.fchmod(fd, 0o666)  # past the umask: other users may claim this id later
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        holder = _holder(path)
        raise DomainBusyError(f"ROS_DOMAIN_ID {domain_id} is in use by another run on this machine"
                         f"{f' ({holder})' if holder else ''}") from None
    os.ftruncate(fd, 0)
    os.write(fd, f"pid {os.getpid()}".encode())
    _held[domain_id] = lock = DomainLock(domain_id, fd)
    return lock


def claim_free_domain(first: int = FIRST_DOMAIN, span: int = DOMAIN_SPAN,
                      start: int | None = None) -> DomainLock:
    """Hold the first id of ``first .. first + span - 1`` no other process holds.

    The search begins at ``start`` (default: pid-based, so parallel runs rarely race
    for the same id) and wraps around. DomainBusyError if every id is taken.
    """
    offset = (os.getpid() if start is None else start - first) % span
    for i in range(span):
        domain_id = first + (offset + i) % span
        if domain_id in _held:
            continue  # ours already, for another purpose
        try:
            return claim_domain(domain_id)
        except DomainBusyError:
            continue
    raise DomainBusyError(f"every ROS_DOMAIN_ID in {first}..{first + span - 1} is in use on this machine")


def claim_consecutive_domains(count: int, first: int = FIRST_DOMAIN,
                              span: int = DOMAIN_SPAN) -> list[DomainLock]:
    """Hold ``count`` consecutive ids of ``first .. first + span - 1`` that no process
    (this one included) holds: for a program that numbers its runs from one base id.
    DomainBusyError if there is no such run of ids."""
    for start in range(first, first + span - count + 1):
        locks: list[DomainLock] = []
        try:
            for domain_id in range(start, start + count):
                if domain_id in _held:
                    raise DomainBusyError(f"ROS_DOMAIN_ID {domain_id} is ours already")
                locks.append(claim_domain(domain_id))
            return locks
        except DomainBusyError:
            for lock in locks:
                lock.release()
    raise DomainBusyError(f"no {count} consecutive free ROS_DOMAIN_IDs in {first}..{first + span - 1}")


def domain_in_use(domain_id: int) -> bool:
    """True if another process holds ``domain_id`` (a snapshot: it may change right after)."""
    if domain_id in _held:
        return False
    try:
        claim_domain(domain_id).release()
    except DomainBusyError:
        return True
    return False


def free_domain_id(seed: int | None = None) -> int:
    """A domain id of the automatic range that no process holds right now (not claimed:
    use :func:`claim_free_domain` to keep others out). Starts at ``seed`` (default pid)."""
    seed = os.getpid() if seed is None else seed
    for i in range(DOMAIN_SPAN):
        domain_id = FIRST_DOMAIN + (seed + i) % DOMAIN_SPAN
        if not domain_in_use(domain_id):
            return domain_id
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


def use_node_dds_profile(env: dict[str, str] | None = None, lockstep: bool = False) -> bool:
    """Point Fast DDS at :data:`NODE_DDS_PROFILE` (``lockstep``: :data:`LOCKSTEP_DDS_PROFILE`)
    in ``env`` (default: os.environ) unless the user chose a profile (the variable set, or
    the file in the cwd); call it before ``rclpy.init``. True if the profile was set."""
    return use_dds_profile(LOCKSTEP_DDS_PROFILE if lockstep else NODE_DDS_PROFILE, env)


def drop_node_dds_profile(env: dict[str, str] | None = None) -> bool:
    """Take the nodes' own profiles (:data:`NODE_DDS_PROFILE`, :data:`LOCKSTEP_DDS_PROFILE`)
    out of ``env`` (default: os.environ), where a process inherited one that is not meant
    for it: the recorder, which records with Fast DDS's defaults (the nodes' profile tunes
    the loop's writers and participants). A profile of the user's stays. True if one was
    taken out."""
    env = os.environ if env is None else env
    if env.get(DDS_PROFILE_VARIABLE) not in (str(NODE_DDS_PROFILE), str(LOCKSTEP_DDS_PROFILE)):
        return False
    del env[DDS_PROFILE_VARIABLE]
    return True


def use_visitor_dds_profile(env: dict[str, str] | None = None) -> bool:
    """As :func:`use_node_dds_profile`, with :data:`VISITOR_DDS_PROFILE` (cr_param, cr_lifecycle)."""
    return use_dds_profile(VISITOR_DDS_PROFILE, env)


def use_dds_profile(profile: Path, env: dict[str, str] | None = None) -> bool:
    """``profile`` for Fast DDS in ``env`` (default: os.environ), unless the user chose one."""
    env = os.environ if env is None else env
    chosen = env.get(DDS_PROFILE_VARIABLE) or Path(DDS_PROFILE_IN_CWD).exists()
    if chosen or not profile.is_file():
        return False
    env[DDS_PROFILE_VARIABLE] = str(profile)
    return True


def isolate_this_process(domain_id: int | None = None) -> None:
    """Apply :func:`isolated_env` to this process before it calls ``rclpy.init``."""
    os.environ.update(isolated_env(domain_id))
