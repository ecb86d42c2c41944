"""The session runner: a recorded, analysed control session in one command.

Starts the recorder, the controller and the plant as separate processes (or plant and
controller composed in one process with ``--composed``), runs for ``--duration``
simulated seconds, stops everything cleanly, then prints the analysis and writes the
plots. Every process runs with localhost-only discovery and the session's own domain id.

    cr_session --scheme adaptive_impedance --duration 10
    cr_session --robot panda --scheme fuzzy_unidirectional
    cr_session --mode lockstep -p adaptive_impedance.Q_c=[50.0,50.0] --out /tmp/runs
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import yaml

from cr_control.core import ros_yaml, topics
from cr_control.core.parameters import Param, ParameterError, validate
from cr_control.core.paths import config_file
from cr_control.core.ros_env import (
    DomainBusyError,
    DomainLock,
    check_domain_id,
    claim_domain,
    claim_free_domain,
    domain_id_arg,
    isolated_env,
)
from cr_control.nodes import memory_reserve
from cr_control.robots import ROBOTS, TASK_SPACE_SCHEMES
from cr_control.schemes.registry import (
    SCHEMES,
    controller_class,
    default_plant_overrides,
    default_scenario,
)
from cr_sim.supervisor import EXIT_ENDED

STARTUP_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 15.0


class SessionError(RuntimeError):
    """A session could not run; the message says why and where the logs are."""


@dataclass
class SessionConfig:
    """What to run."""

    scheme: str = "adaptive_impedance"
    duration: float = 10.0
    mode: str = "realtime"
    composed: bool = False
    record: bool = True
    out: Path = Path("sessions")
    params_files: list[Path] = field(default_factory=list)
    overrides: list[str] = field(default_factory=list)
    domain_id: int | None = None
    name: str | None = None
    robot: str | None = None
    #: A second scheme, started inactive (autostart false) and switched to live at
    #: ``switch_at`` simulated seconds (cr_lifecycle switch): ``--switch-to``, ``--switch-at``.
    switch_to: str | None = None
    switch_at: float = 0.0


class EndedEarlyError(SessionError):
    """The plant ended the session early (exit code
    :data:`cr_sim.supervisor.EXIT_ENDED`): in a safe stop that no command followed, or with
    no valid command after its start. ``result``: the session's files (the recording holds
    everything up to the end); the message: the plant's line saying why."""

    def __init__(self, result: SessionResult, line: str) -> None:
        super().__init__(f"the plant ended the session early: {line or 'see its log'} "
                         f"(logs: {result.logs})")
        self.result = result


@dataclass
class SessionResult:
    """Where a finished session put its files."""

    directory: Path
    mcap: Path | None
    params: Path
    logs: Path
    mode: str = "realtime"


#: Parameters the recorder node declares (cr_control/recording/recorder.py; a test
#: checks this list against a running Recorder).
RECORDER_PARAMETERS = ("output", "topics", "optional_topics", "parameter_nodes", "ready_timeout",
                       "compression")
#: Node names of a params file that address every node.
WILDCARD_NODES = ("**", "/**")


def _load_params_file(path: Path) -> dict[str, dict[str, Any]]:
    """A ROS params file as {node: {parameter: value}}; SessionError saying what is wrong.

    Read as every YAML input is (:func:`cr_control.core.ros_yaml.read_file`): a regular file
    of at most 1 MiB of UTF-8 text, no aliases, nesting at most 64 deep; a named pipe or
    ``/dev/zero`` is refused without reading it."""
    try:
        data = ros_yaml.load(ros_yaml.read_file(path))
    except OSError as exc:
        raise SessionError(f"params file {path}: {exc.strerror or exc}") from None
    except ValueError as exc:       # not a regular file, too large, not UTF-8
        raise SessionError(f"params file {path}: {exc}") from None
    except yaml.YAMLError as exc:
        raise SessionError(f"params file {path}: not valid YAML: "
                           f"{ros_yaml.describe_error(exc)}") from None
    expected = f"expected '{ros_yaml.PARAMS_FILE_FORM}'"
    if ros_yaml.is_empty_params(data):
        raise SessionError(f"params file {path}: empty, no node's parameters ({expected})")
    if not isinstance(data, dict):
        raise SessionError(f"params file {path}: not a ROS params file ({expected}, "
                           f"found a {type(data).__name__})")
    nodes = {}
    for node, body in data.items():
        values = body.get("ros__parameters") if isinstance(body, dict) else None
        if not isinstance(values, dict):
            raise SessionError(f"params file {path}: node {node!r} has no ros__parameters "
                               f"mapping ({expected})")
        nodes[str(node) if str(node) in WILDCARD_NODES else str(node).lstrip("/")] = dict(values)
    return nodes


def _parse_override(text: str) -> tuple[str, str, Any]:
    """``node.param=value`` -> (node, param, YAML-parsed value)."""
    key, sep, raw = text.partition("=")
    node, dot, name = key.partition(".")
    if not sep or not dot or not node or not name:
        raise SessionError(f"override {text!r} is not of the form node.param=value")
    try:
        return node, name, ros_yaml.load(raw)
    except yaml.YAMLError as exc:
        raise SessionError(f"override {text!r}: value is not valid YAML: "
                           f"{ros_yaml.describe_error(exc)}") from None


def _merge(params: dict[str, dict[str, Any]], node: str, values: dict[str, Any], source: str) -> None:
    """Add ``values`` for ``node`` (or every node for a wildcard) from ``source``."""
    targets = list(params) if node in WILDCARD_NODES else [node]
    for target in targets:
        if target not in params:
            raise SessionError(f"{source}: no node {target!r} in this session "
                               f"(nodes: {', '.join(params)})")
        params[target].update(values)


def node_specs(node: str, params: dict[str, Any]) -> list[Param] | None:
    """The declared parameters of session node ``node`` given its ``params`` (None for
    the recorder, which declares plain ROS parameters: see RECORDER_PARAMETERS)."""
    if node == "recorder":
        return None
    if node == "plant":
        from cr_sim.plant_node import plant_parameters
        from cr_sim.plants.registry import SCENARIOS

        scenario = params.get("scenario")
        if scenario not in SCENARIOS:
            raise SessionError(f"plant.scenario {scenario!r} is not one of {sorted(SCENARIOS)}")
        return plant_parameters(scenario)
    try:
        return controller_class(node).parameters(params)
    except ParameterError as exc:
        raise SessionError(f"{node}: {exc}") from None


#: Real-time sessions publish ~/reference and ~/status every this many cycles.
REALTIME_DIAGNOSTICS_EVERY = 10


def session_parameters(cfg: SessionConfig, mcap: Path) -> dict[str, dict[str, Any]]:
    """Parameters of every node of the session: shipped defaults, files, overrides.

    SessionError naming the file, node or parameter for anything a node would not take:
    unreadable or malformed files, unknown nodes, unknown parameter names, refused values.
    """
    schemes = session_schemes(cfg)
    if cfg.robot is None:
        scenario = default_scenario(cfg.scheme)
        params = {s: _load_params_file(config_file(f"{s}.yaml"))[s] for s in schemes}
        params.update(_load_params_file(config_file(f"plant_{scenario}.yaml")))
        params["plant"].update(default_plant_overrides(cfg.scheme))
    else:                               # the robot's wiping task (cr_control.robots)
        params = {s: _load_params_file(config_file(f"robots/{cfg.robot}/{s}.yaml"))[s]
                  for s in schemes}
        params.update(_load_params_file(config_file(f"robots/{cfg.robot}/plant.yaml")))
        scenario = params["plant"]["scenario"]
    params["plant"].update(scenario=scenario, mode=cfg.mode, duration=float(cfg.duration),
                           wait_for_recorder=cfg.record)
    for scheme in schemes:
        params[scheme]["lockstep"] = cfg.mode == "lockstep"
        if cfg.mode == "realtime":
            # Each publish costs about as much as the whole control law (benchmark: controller
            # "out" 426 us for command + reference + status vs 150 us with decimated
            # diagnostics): in real time the diagnostics go out at 100 Hz, the command every
            # cycle. Lockstep keeps every cycle (thesis figures, offline equality);
            # -p <scheme>.diagnostics_every=1 gives the full rate in real time too.
            params[scheme]["diagnostics_every"] = REALTIME_DIAGNOSTICS_EVERY
    if cfg.mode == "realtime":
        params["plant"]["contact_wrench_every"] = REALTIME_DIAGNOSTICS_EVERY
    if cfg.switch_to is not None:
        params[cfg.switch_to]["autostart"] = False
    params["recorder"] = {
        "output": str(mcap),
        "topics": [topics.JOINT_STATES, topics.WRENCH, topics.JOINT_COMMANDS, topics.PLANT_TIMING,
                   topics.PARAMETER_EVENTS]
        + [t for s in schemes for t in (topics.reference_topic(s), topics.status_topic(s))]
        + ([topics.CLOCK] if cfg.mode == "lockstep" else [])
        + ([f"/{s}/transition_event" for s in schemes] if cfg.switch_to else []),
        # Recorded when they appear, never waited for (/diagnostics, markers).
        "optional_topics": [topics.CLOCK, topics.PLANT_SENSORS, topics.CONTACT_WRENCH, topics.DIAGNOSTICS,
                            topics.PLANT_MARKERS] + [topics.markers_topic(s) for s in schemes],
        "parameter_nodes": ["plant", *schemes],
        "ready_timeout": 30.0,
    }
    for path in cfg.params_files:
        for node, values in _load_params_file(Path(path)).items():
            _merge(params, node, values, f"params file {path}")
    for text in cfg.overrides:
        node, name, value = _parse_override(text)
        _merge(params, node, {name: value}, f"override {text!r}")
    _check_parameters(params)
    return params


def session_schemes(cfg: SessionConfig) -> list[str]:
    """The session's controllers: the scheme, and the one it switches to."""
    return [cfg.scheme] + ([cfg.switch_to] if cfg.switch_to else [])


def _check_parameters(params: dict[str, dict[str, Any]]) -> None:
    """SessionError for a parameter a node does not have or would refuse at start."""
    from cr_control.nodes.ros_parameters import refuse_unknown

    for node, values in params.items():
        specs = node_specs(node, values)
        try:
            refuse_unknown(node, values, RECORDER_PARAMETERS if specs is None else
                           [spec.name for spec in specs])
        except ParameterError as exc:
            raise SessionError(str(exc)) from None
        for spec in specs or ():
            ok, reason, _ = validate(spec, values.get(spec.name, spec.default))
            if not ok:
                raise SessionError(f"{node}: {reason}")
    _check_robot_descriptions(params)


#: The parameters that name a node's robot description and its chain.
ROBOT_KEYS = ("robot_description", "urdf_file", "base_link", "tip_link")


def _check_robot_descriptions(params: dict[str, dict[str, Any]]) -> None:
    """SessionError for a robot description a node would refuse (too large or deep, an
    entity, non-physical masses, inertias or limits: :func:`cr_control.models.urdf.load_chain`),
    before any process starts: the session refuses in one line, never with a node's crash."""
    from cr_control.models.urdf import RobotModelError, load_chain

    checked: dict[tuple, str | None] = {}
    for node, values in params.items():
        specs = {spec.name: spec.default for spec in node_specs(node, values) or ()}
        if not all(key in specs for key in ROBOT_KEYS):
            continue
        key = tuple(str(values.get(k, specs[k])) for k in ROBOT_KEYS)
        if not (key[0] or key[1]):
            continue
        if key not in checked:
            try:
                load_chain(*key)
                checked[key] = None
            except RobotModelError as exc:
                checked[key] = str(exc)
        if checked[key] is not None:
            raise SessionError(f"{node}: {checked[key]}")


def _check_switch(cfg: SessionConfig) -> None:
    """SessionError unless ``cfg.switch_to`` can take over from ``cfg.scheme`` live."""
    other = cfg.switch_to
    if other not in SCHEMES:
        raise SessionError(f"--switch-to: unknown scheme {other!r}; known: {sorted(SCHEMES)}")
    if other == cfg.scheme:
        raise SessionError(f"--switch-to {other}: the session already runs it")
    if cfg.composed:
        raise SessionError("--switch-to needs the controllers as processes (not --composed)")
    if cfg.robot is not None and other not in TASK_SPACE_SCHEMES:
        raise SessionError(f"--switch-to {other}: runs on its thesis plant only; on a robot: "
                           f"{', '.join(TASK_SPACE_SCHEMES)}")
    if cfg.robot is None and default_scenario(other) != default_scenario(cfg.scheme):
        raise SessionError(f"--switch-to {other}: its plant is {default_scenario(other)}, "
                           f"not {cfg.scheme}'s {default_scenario(cfg.scheme)}")
    if not 0.0 <= cfg.switch_at < cfg.duration:
        raise SessionError(f"--switch-at {cfg.switch_at:g}: must be within the session "
                           f"(0 <= T < --duration {cfg.duration:g})")


def _check_out(out: Path) -> None:
    """SessionError unless session directories can be made under ``out``."""
    existing = out.absolute()
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise SessionError(f"--out {out}: {existing} is not a directory")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise SessionError(f"--out {out}: no permission to create anything in {existing}")


def _check_name(name: str) -> None:
    """SessionError unless ``name`` is one plain directory name (the session directory
    must be made right under ``--out``: no path separator, no ``..``, not absolute)."""
    seps = {"/", os.sep, os.altsep} - {None}
    why = ("it is empty or blank" if not name.strip() else
           "it is '.' or '..'" if name in (".", "..") else
           "it contains a path separator" if any(sep in name for sep in seps) else
           "it contains a NUL character" if "\0" in name else "")
    if why:
        raise SessionError(f"--name {name!r}: must be a plain directory name to make under --out "
                           f"({why})")


def _new_directories(path: Path) -> list[Path]:
    """``path`` and those of its parents that do not exist yet, outermost first."""
    missing = []
    while not path.exists() and path != path.parent:
        missing.append(path)
        path = path.parent
    return missing[::-1]


class ProcessGroup:
    """Child processes of one run: each in a process group of its own, output to a log file."""

    def __init__(self, logs: Path, env: dict[str, str], progress=print,
                 inherit: Iterable[int] = ()):
        """``inherit``: file descriptors the children keep open (e.g. a domain lock, so
        that it stays held while any of them runs)."""
        self.logs = logs
        self.env = env
        self.progress = progress
        self.inherit = tuple(inherit)
        self.processes: dict[str, subprocess.Popen] = {}
        self.one_shot: set[str] = set()      # may end before the main process (code 0)
        self._files: list = []

    def start(self, name: str, cmd: list[str], one_shot: bool = False) -> subprocess.Popen:
        """Start ``cmd`` as ``name``, its output going to logs/<name>.log; a ``one_shot``
        process does its job and ends (only a non-zero exit is a failure)."""
        if one_shot:
            self.one_shot.add(name)
        log = open(self.logs / f"{name}.log", "w")  # noqa: SIM115 - closed by stop()
        self._files.append(log)
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=self.env,
                                start_new_session=True, pass_fds=self.inherit)
        self.processes[name] = proc
        return proc

    def tail(self, name: str, lines: int = 15) -> str:
        """The last lines of a process's log, indented (Fast DDS shared-memory noise left out)."""
        path = self.logs / f"{name}.log"
        text = path.read_text(errors="replace").splitlines() if path.exists() else []
        return "\n".join(f"    {line}" for line in text[-lines:] if "RTPS_TRANSPORT_SHM" not in line)

    def last_line(self, name: str, marker: str) -> str:
        """The message of the last log line of ``name`` containing ``marker`` ("" if none)."""
        try:
            text = (self.logs / f"{name}.log").read_text(errors="replace")
        except OSError:
            return ""
        lines = [ln for ln in text.splitlines() if marker in ln]
        return lines[-1].split("]: ", 1)[-1] if lines else ""

    def wait(self, main_name: str, budget: float, progress_marker: str) -> None:
        """Wait for ``main_name`` to end, echoing its progress lines; SessionError (with the
        log tail) if it fails, takes longer than ``budget`` s, or another process dies first."""
        main = self.processes[main_name]
        deadline = time.monotonic() + budget
        last = ""
        while main.poll() is None:
            for name, proc in self.processes.items():
                if proc is not main and proc.poll() is not None and (
                        name not in self.one_shot or proc.returncode != 0):
                    raise SessionError(f"{name} exited early (code {proc.returncode}):\n{self.tail(name)}")
            if time.monotonic() > deadline:
                raise SessionError(
                    f"{main_name} did not finish within {budget:.0f} s:\n{self.tail(main_name)}")
            line = self.last_line(main_name, progress_marker)
            if line and line != last:
                self.progress(f"  {line}")
                last = line
            time.sleep(0.25)
        if main.returncode != 0:
            raise SessionError(f"{main_name} failed (code {main.returncode}):\n{self.tail(main_name)}")

    def stop(self) -> None:
        """Stop every process still running: SIGINT, then SIGKILL after a timeout."""
        for proc in self.processes.values():
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
        deadline = time.monotonic() + STOP_TIMEOUT_S
        for name, proc in self.processes.items():
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.progress(f"{name} did not stop on SIGINT: killing it")
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        for log in self._files:
            log.close()


class Session:
    """The processes of one session and their logs.

    Everything is checked before anything is created: the configuration, ``--out``, the
    params files and overrides (unknown nodes and parameter names refused). :meth:`run`
    then claims the domain id (machine-wide, see :mod:`cr_control.core.ros_env`): the
    one asked for (``domain_id``, else $ROS_DOMAIN_ID) or, if none, a free one.
    """

    def __init__(self, cfg: SessionConfig, progress=print):
        if cfg.scheme not in SCHEMES:
            raise SessionError(f"unknown scheme {cfg.scheme!r}; known: {sorted(SCHEMES)}")
        if cfg.robot is not None and cfg.robot not in ROBOTS:
            raise SessionError(f"unknown robot {cfg.robot!r}; known: {sorted(ROBOTS)}")
        if cfg.robot is not None and cfg.scheme not in TASK_SPACE_SCHEMES:
            raise SessionError(f"{cfg.scheme} runs on its thesis plant only; on a robot: "
                               f"{', '.join(TASK_SPACE_SCHEMES)}")
        if cfg.mode not in ("realtime", "lockstep"):
            raise SessionError(f"mode must be realtime or lockstep, not {cfg.mode!r}")
        if not 0 < cfg.duration < math.inf:
            raise SessionError(f"duration must be a finite number > 0, not {cfg.duration}")
        if cfg.switch_to is not None:
            _check_switch(cfg)
        if cfg.name is not None:
            _check_name(cfg.name)
        self.cfg = cfg
        self.progress = progress
        stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
        robot = f"-{cfg.robot}" if cfg.robot else ""
        name = cfg.name or (f"{stamp}{robot}-{cfg.scheme}-{cfg.mode}"
                            f"{'-composed' if cfg.composed else ''}")
        _check_out(Path(cfg.out))
        self.dir = Path(cfg.out) / name
        self.logs = self.dir / "logs"
        self.mcap = self.dir / "session.mcap"
        self.params_path = self.dir / "params.yaml"
        self.params = session_parameters(cfg, self.mcap)
        self.requested_domain = self._requested_domain()
        self.env = isolated_env(self.requested_domain)
        self.env.setdefault("PYTHONUNBUFFERED", "1")
        memory_reserve.loop_env(self.env)      # one malloc arena: the reserve serves every thread
        self.domain: DomainLock | None = None
        self.group = ProcessGroup(self.logs, self.env, progress)

    def _requested_domain(self) -> int | None:
        """The domain id asked for: ``cfg.domain_id``, else $ROS_DOMAIN_ID, else None."""
        if self.cfg.domain_id is not None:
            value, source = self.cfg.domain_id, "--domain-id"
        elif os.environ.get("ROS_DOMAIN_ID", "").strip():
            value, source = os.environ["ROS_DOMAIN_ID"].strip(), "$ROS_DOMAIN_ID"
        else:
            return None
        try:
            return check_domain_id(value)
        except ValueError as exc:
            raise SessionError(f"{source}: {exc}") from None

    def _claim_domain(self) -> DomainLock:
        """Hold the session's domain id; SessionError if another run on this machine has it."""
        if self.requested_domain is None:
            try:
                return claim_free_domain()
            except DomainBusyError as exc:
                raise SessionError(f"{exc}; pass --domain-id to use another id") from None
        try:
            return claim_domain(self.requested_domain)
        except DomainBusyError as exc:
            hint = ("pass another --domain-id" if self.cfg.domain_id is not None else
                    "unset ROS_DOMAIN_ID (a free id is then chosen) or pass --domain-id")
            raise SessionError(f"{exc}: refusing to start, it would mix with that run; "
                               f"{hint}") from None

    @property
    def processes(self) -> dict[str, subprocess.Popen]:
        """The session's processes by name."""
        return self.group.processes

    def _start(self, name: str, module: str, *args: str) -> None:
        self.group.start(name, [sys.executable, "-m", module, *args,
                                "--ros-args", "--params-file", str(self.params_path)])

    def _create_files(self) -> None:
        """The session directory, its logs folder and params.yaml (nothing left on failure)."""
        created = _new_directories(self.logs)
        try:
            self.logs.mkdir(parents=True, exist_ok=True)
            self.params_path.write_text(yaml.safe_dump(
                {node: {"ros__parameters": values} for node, values in self.params.items()},
                sort_keys=False))
        except OSError as exc:
            if created:
                shutil.rmtree(created[0], ignore_errors=True)
            raise SessionError(f"cannot create {self.dir}: {exc.strerror or exc}") from None

    def run(self, domain: DomainLock | None = None) -> SessionResult:
        """Run the session to the end; SessionError (with log tails) if a process fails.
        ``domain``: a domain id the caller holds already (and releases), e.g. cr_fuzz, whose
        own node joins it before the session starts."""
        cfg = self.cfg
        self.domain = domain or self._claim_domain()
        try:
            self.env["ROS_DOMAIN_ID"] = str(self.domain.domain_id)
            self.group.inherit = (self.domain.fileno(),)
            self._create_files()
            self.progress(f"session {self.dir} (ROS_DOMAIN_ID={self.env['ROS_DOMAIN_ID']}, "
                          f"discovery {self.env['ROS_AUTOMATIC_DISCOVERY_RANGE']})")
            main = "container" if cfg.composed else "plant"
            ended = False
            try:
                if cfg.record:
                    self._start("recorder", "cr_control.recording.recorder")
                if cfg.composed:
                    self._start(main, "cr_control.tools.container", cfg.scheme)
                else:
                    for scheme in session_schemes(cfg):
                        self._start(scheme, "cr_control.nodes.controller_node", scheme)
                    if cfg.switch_to:
                        self.group.start("switch", [
                            sys.executable, "-m", "cr_control.tools.lifecycle_tool",
                            "--timeout", str(STARTUP_TIMEOUT_S), "switch", cfg.scheme,
                            cfg.switch_to, "--at", repr(cfg.switch_at),
                            # lockstep stamps the plant's time from 0: the switch lands at
                            # --switch-at however late the tool subscribes
                            *(["--plant-time"] if cfg.mode == "lockstep" else [])],
                            one_shot=True)
                    self._start(main, "cr_sim.plant_node")
                budget = STARTUP_TIMEOUT_S + cfg.duration * (2.0 if cfg.mode == "realtime" else 20.0)
                try:
                    self.group.wait(main, budget, "] [plant]: t=")
                except SessionError:
                    if self.processes[main].returncode != EXIT_ENDED:
                        raise
                    ended = True
            finally:
                self.stop()
        finally:
            if domain is None:
                self.domain.release()
        result = SessionResult(self.dir, self.mcap if cfg.record else None, self.params_path,
                               self.logs, cfg.mode)
        if ended:
            raise EndedEarlyError(result, self.group.last_line(main, "ENDED: "))
        return result

    def stop(self) -> None:
        """Stop every process still running: SIGINT, then SIGKILL after a timeout."""
        self.group.stop()


def analyse(result: SessionResult, progress=print) -> None:
    """Print the session's metrics and write its plots next to the recording."""
    from cr_control.analysis import analyze
    from cr_control.analysis.analyze import format_metrics, load_session, metrics, plot_session

    try:
        session = load_session(result.mcap)
    except analyze.SessionError as exc:
        raise SessionError(f"cannot analyse the recording: {exc}") from None
    values = metrics(session)
    progress(format_metrics([(session.controller or result.directory.name, values)]))
    for line in analyze.loop_summary(values, realtime=result.mode == "realtime"):
        progress(line)
    paths = plot_session(session, result.directory / "plots")
    progress(f"plots: {', '.join(str(p) for p in paths)}")


def build_parser() -> argparse.ArgumentParser:
    """Command-line interface of cr_session."""
    p = argparse.ArgumentParser(
        prog="cr_session", description=__doc__.split("\n\n")[0],
        epilog="exit status: 0 done; 1 the session failed (one line on stderr); 3 the plant "
               "ended it early, in a safe stop no command followed or with no valid command "
               "after its start (its reason on stderr, the recording kept); 130 interrupted")
    p.add_argument("--scheme", default="adaptive_impedance", choices=sorted(SCHEMES))
    p.add_argument("--robot", choices=sorted(ROBOTS),
                   help="run on this robot's URDF, wiping a table (task-space schemes; "
                        "default: the scheme's thesis plant)")
    p.add_argument("--duration", type=float, default=10.0, help="simulated seconds (default 10)")
    p.add_argument("--mode", default="realtime", choices=["realtime", "lockstep"])
    p.add_argument("--composed", action="store_true", help="plant and controller in one process")
    p.add_argument("--out", type=Path, default=Path("sessions"), help="parent directory of sessions")
    p.add_argument("--name", help="session directory name (default: time, scheme, mode)")
    p.add_argument("--params-file", type=Path, action="append", default=[],
                   help="extra ROS params file(s) (node names: plant, recorder, the scheme)")
    p.add_argument("-p", "--set", dest="overrides", action="append", default=[],
                   metavar="NODE.PARAM=VALUE", help="override one parameter, e.g. plant.stiffness=300.0")
    p.add_argument("--switch-to", metavar="SCHEME",
                   help="also start SCHEME inactive and switch to it live at --switch-at "
                        "(lifecycle transitions: the first is deactivated, SCHEME activated)")
    p.add_argument("--switch-at", type=float, default=0.0, metavar="T",
                   help="simulated seconds after the start at which to switch (default 0)")
    p.add_argument("--no-record", action="store_true", help="run without the recorder")
    p.add_argument("--no-analysis", action="store_true", help="do not analyse the recording")
    p.add_argument("--domain-id", type=domain_id_arg,
                   help="ROS_DOMAIN_ID; refused if another run on this machine holds it "
                        "(default: $ROS_DOMAIN_ID, else a free id in 1..50)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run one session from the command line."""
    args = build_parser().parse_args(argv)
    cfg = SessionConfig(scheme=args.scheme, duration=args.duration, mode=args.mode,
                        composed=args.composed, record=not args.no_record, out=args.out,
                        params_files=args.params_file, overrides=args.overrides,
                        domain_id=args.domain_id, name=args.name, robot=args.robot,
                        switch_to=args.switch_to, switch_at=args.switch_at)
    try:
        session = Session(cfg)
        result = session.run()
        print(f"recording: {result.mcap}" if result.mcap else "not recorded")
        print(f"logs: {result.logs}")
        if result.mcap and not args.no_analysis:
            analyse(result)
    except EndedEarlyError as exc:
        print(f"cr_session: {exc}", file=sys.stderr)
        if exc.result.mcap:
            print(f"recording: {exc.result.mcap}")
        return EXIT_ENDED
    except (SessionError, OSError) as exc:
        print(f"cr_session: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("cr_session: interrupted; processes stopped", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
