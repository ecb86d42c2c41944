"""Every command the README and docs/usage.md show is run here, so the pages stay true;
the README's Python example too (:func:`test_the_readme_python_example_runs`).

The commands are read from the ``sh`` blocks of both pages. Two kinds are not run, as the
pages say: the ROS-install commands (``ros2 ...``, which need a ROS 2 install; this machine
has none) and ``make test`` / ``make test-fast`` (what CI runs: this suite itself). Every
other command must match a runner below, which runs it as written except for these stated
substitutions:

- ``--domain-id 12`` (an example id) -> this test's domain id, where the README's nodes run,
  with ``--timeout 30`` (the default 3 s bounds discovery, slower on a loaded CI machine);
- ``sessions/<dir>/session.mcap``, ``a.mcap b.mcap c.mcap`` -> recordings made here;
- ``OUT``, ``/tmp/runs``, ``compare/`` -> a temporary directory;
- sessions run 1 s (``--duration 1`` added; ``make demo DURATION=1``; a live switch
  ``--switch-at 0.5`` and 1.5 s) and recordings go to a temporary ``--out``, so the test
  stays short;
- the README's long-running nodes (``.venv/bin/plant``, ``.venv/bin/adaptive_impedance``) run
  until the commands addressed to them are done, then get Ctrl-C;
- ``tool.yaml``, ``sweeps/...``, ``tuned/``, ``report/`` -> the temporary directory, and the
  example sweep and tuning specs are run as copies with short runs (0.5 s; 5 s for tuning),
  two grid values per parameter and two tuning samples (the full specs' figures: docs).

A command no runner knows fails :func:`test_every_readme_command_has_a_runner`.
"""

from __future__ import annotations

import json
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from ros_probe import next_domain

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: The pages whose commands are run here: the README and the reference it points to.
PAGES = (README, ROOT / "docs" / "usage.md")
#: Not run here, as the pages say: the ROS-install commands, and the suite itself
#: (``make test``, ``make test-fast``).
NOT_RUN = (re.compile(r"^ros2 "), re.compile(r"^make test\b"))


def readme_commands() -> list[str]:
    """The commands of the pages' ``sh`` blocks, each once: continuations joined, comments
    dropped."""
    out: list[str] = []
    for page in PAGES:
        for block in re.findall(r"```sh\n(.*?)```", page.read_text(), flags=re.S):
            text = block.replace("\\\n", " ")
            for line in text.splitlines():
                line = re.sub(r"\s+#.*$", "", line).strip()
                if line and not line.startswith("#"):
                    line = re.sub(r"\s+", " ", line)
                    if line not in out:
                        out.append(line)
    return out


def run_commands() -> list[str]:
    return [c for c in readme_commands() if not any(p.search(c) for p in NOT_RUN)]


class Readme:
    """Runs README commands in one environment (domain id, temporary directories)."""

    def __init__(self, env: dict[str, str], tmp: Path, quick_report: Path | None = None):
        self.env, self.tmp = env, tmp
        #: DIR of the session's cr_reproduce --quick run (conftest.reproduce_quick)
        self.quick_report = quick_report
        self.domain = env["ROS_DOMAIN_ID"]
        self.recordings: list[Path] = []
        self.daemons: list[subprocess.Popen] = []

    def argv(self, command: str) -> list[str]:
        command = command.replace("--domain-id 12", f"--domain-id {self.domain} --timeout 30")
        args = shlex.split(command)
        if args[0].startswith(".venv/"):
            args[0] = str(ROOT / args[0])
        return args

    def run(self, args: list[str], timeout: float = 300.0,
            own_domain: bool = False) -> subprocess.CompletedProcess:
        """``args`` run to the end; ``own_domain``: a session, which takes a free domain id
        of its own (it refuses one another run holds, as this test holds its own)."""
        env = {k: v for k, v in self.env.items() if k != "ROS_DOMAIN_ID" or not own_domain}
        proc = subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True,
                              timeout=timeout)
        assert "Traceback" not in proc.stderr, proc.stderr
        return proc

    def session(self, command: str) -> subprocess.CompletedProcess:
        args = self.argv(command)
        if "--help" not in args:
            out = self.tmp / f"sessions{len(self.recordings)}"
            args = [a if a != "/tmp/runs" else str(out) for a in args]
            switch_at = 0.5 if "--switch-at" in args else 0.0   # then 0.5 s of the second law
            if switch_at:
                args[args.index("--switch-at") + 1] = f"{switch_at:g}"
            args += ["--duration", f"{switch_at + 1.0:g}"]
            if "--out" not in args:
                args += ["--out", str(out)]
        proc = self.run(args, own_domain=True)
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
        found = re.search(r"^recording: (.+\.mcap)$", proc.stdout, flags=re.M)
        if found:
            self.recordings.append(Path(found[1]))
        return proc

    def start(self, command: str) -> None:
        proc = subprocess.Popen(self.argv(command), cwd=ROOT, env=self.env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        self.daemons.append(proc)

    def wait_for_nodes(self) -> None:
        """Until the README's nodes answer (a cr_param list with a long timeout)."""
        probe = self.run(self.argv(".venv/bin/cr_param --domain-id 12 list /adaptive_impedance"))
        assert probe.returncode == 0, probe.stderr

    def stop_daemons(self) -> None:
        for proc in self.daemons:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in self.daemons:
            try:
                proc.communicate(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
        self.daemons.clear()


def expect(code: int) -> Callable[[Readme, str], None]:
    def run(readme: Readme, command: str) -> None:
        proc = readme.run(readme.argv(command))
        assert proc.returncode == code, (command, proc.stdout[-1500:], proc.stderr[-1500:])
    return run


def analyze(readme: Readme, command: str) -> None:
    mcaps = [str(p) for p in readme.recordings]
    assert len(mcaps) >= 3, "the sessions above made the recordings"
    command = command.replace("sessions/<dir>/session.mcap", mcaps[0])
    command = command.replace("a.mcap b.mcap c.mcap", " ".join(mcaps[:3]))
    command = command.replace("compare/", str(readme.tmp / "compare"))
    proc = readme.run(readme.argv(command))
    assert proc.returncode == 0, proc.stderr


def offline_chapter(readme: Readme, command: str) -> None:
    args = readme.argv(command.replace(" OUT", f" {readme.tmp / 'chapter'}"))
    args[0] = str(ROOT / ".venv/bin/python") if args[0] == "python" else args[0]
    proc = readme.run(args, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert list((readme.tmp / "chapter").rglob("*.png"))


def _short_spec(readme: Readme, path: str) -> str:
    """A copy of an example spec with 0.5 s runs, two values per grid parameter, two samples."""
    import yaml

    spec = yaml.safe_load((ROOT / path).read_text())
    # tuning judges a trial infeasible with a command at its clip for over 1 % of the run:
    # the chapter 3 start transient clips 41 ms, so its runs stay 5 s long
    spec["duration"] = 5.0 if "search" in spec else 0.5
    if "vary" in spec:
        spec["vary"] = {k: v[:2] if isinstance(v, list) else v for k, v in spec["vary"].items()}
    if "samples" in spec:
        spec["samples"] = 2
    out = readme.tmp / Path(path).name
    out.write_text(yaml.safe_dump(spec))
    return str(out)


def experiments(readme: Readme, command: str) -> None:
    args = readme.argv(command)
    args = [_short_spec(readme, a) if a.startswith("docs/examples/") else a for a in args]
    i = args.index("--out")
    args[i + 1] = str(readme.tmp / args[i + 1])
    quick = "cr_reproduce" in args[0] and "--quick" in args and readme.quick_report
    if quick:
        # the session's quick run's points, which the command resumes from (the same SPECs):
        # the command line is tested without computing the quick report twice in CI
        shutil.copytree(readme.quick_report / "runs", Path(args[i + 1]) / "runs")
    proc = readme.run(args, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    if "cr_reproduce" in command:
        # the quick run's claims: every chapter, each with numbers and a computed verdict
        # (test_reproduce.py checks that the verdicts follow the rules)
        claims = json.loads((Path(args[i + 1]) / "claims.json").read_text())
        assert {c["chapter"] for c in claims} == {"2", "3", "4", "5", "6", "C"}
        for c in claims:
            assert c["verdict"] in ("reproduced", "not reproduced", "reproduced with correction")
            assert any(isinstance(v, (int, float)) for v in c["measured"].values()), c["claim"]
    if quick:
        assert (Path(args[i + 1]) / "claims.json").read_text() == \
            (readme.quick_report / "claims.json").read_text()


def identify(readme: Readme, command: str) -> None:
    args = [a if a != "tool.yaml" else str(readme.tmp / "tool.yaml") for a in readme.argv(command)]
    proc = readme.run(args, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "tool_mass" in (readme.tmp / "tool.yaml").read_text()


def make_demo(readme: Readme, command: str) -> None:
    args = readme.argv(command) + ["DURATION=1", f"OUT={readme.tmp / 'demo'}"]
    proc = readme.run(args, timeout=600, own_domain=True)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "recording:" in proc.stdout and "plots:" in proc.stdout


#: (pattern of a README command, how it is run). The long-running nodes are started first;
#: the commands addressed to them (cr_param, cr_lifecycle) then run against them.
RUNNERS: list[tuple[re.Pattern, Callable[[Readme, str], None]]] = [
    (re.compile(r"^make demo\b"), make_demo),
    (re.compile(r"^\.venv/bin/cr_session "), lambda r, c: r.session(c)),
    (re.compile(r"^\.venv/bin/(plant|adaptive_impedance) --ros-args"), lambda r, c: r.start(c)),
    (re.compile(r"^\.venv/bin/cr_param .* set .*-1\.0\]"), expect(1)),     # refused
    (re.compile(r"^\.venv/bin/cr_param "), expect(0)),
    (re.compile(r"^\.venv/bin/cr_lifecycle .* set .* deactivate$"), expect(0)),
    (re.compile(r"^\.venv/bin/cr_lifecycle "), expect(0)),
    (re.compile(r"^\.venv/bin/cr_analyze "), analyze),
    (re.compile(r"^python -m cr_control\.analysis\.chapter\d OUT$"), offline_chapter),
    (re.compile(r"^\.venv/bin/cr_identify_tool "), identify),
    (re.compile(r"^\.venv/bin/cr_(sweep|tune|reproduce) "), experiments),
]
#: The order runners run in: sessions (recordings) first, then the nodes and what talks to
#: them, then the analysis.
ORDER = ("make demo", "cr_session", "plant", "adaptive_impedance", "cr_param", "cr_lifecycle",
         "cr_analyze", "python -m", "cr_identify_tool", "cr_sweep", "cr_tune", "cr_reproduce")


def runner(command: str) -> Callable[[Readme, str], None] | None:
    return next((run for pattern, run in RUNNERS if pattern.search(command)), None)


def test_every_readme_command_has_a_runner():
    commands = run_commands()
    assert len(commands) >= 10
    assert [c for c in commands if runner(c) is None] == []


def test_the_readme_python_example_runs():
    """The README's offline example, run as a user runs it (no ROS): with the thesis's gains
    the position error falls from 70.7 mm to 9.5 mm in 10 s, with Q_c x10 to 0.7 mm, as the
    README says."""
    [example] = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    proc = subprocess.run([sys.executable, "-c", example], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.splitlines()
    print("\n".join(lines))
    errors = [re.search(r"position error ([\d.]+) mm at 0 s, ([\d.]+) mm at 10 s", line).groups()
              for line in lines]
    assert errors == [("70.7", "9.5"), ("70.7", "0.7")]
    assert all(re.search(r"10000 cycles", line) for line in lines)


def _rank(command: str) -> int:
    """The position in ORDER of the command's program (``make demo``, ``python -m``, or the
    executable's name)."""
    words = command.split()
    program = " ".join(words[:2]) if words[0] in ("make", "python") else words[0].rpartition("/")[2]
    return ORDER.index(program)


@pytest.mark.ros
def test_the_readme_commands_run(tmp_path, ros_env, reproduce_quick):
    readme = Readme(ros_env, tmp_path, reproduce_quick)
    commands = sorted(run_commands(), key=_rank)
    waited = False
    try:
        for command in commands:
            if not waited and _rank(command) >= ORDER.index("cr_param"):
                readme.wait_for_nodes()
                waited = True
            start = time.monotonic()
            runner(command)(readme, command)
            print(f"README ({time.monotonic() - start:5.1f} s): {command}")
    finally:
        readme.stop_daemons()


@pytest.fixture
def ros_env(ros_env):
    """The README's nodes and sessions on one domain of this test."""
    ros_env = dict(ros_env)
    ros_env["ROS_DOMAIN_ID"] = str(next_domain())
    return ros_env
