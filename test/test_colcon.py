"""The package builds with `colcon build` and the install tree works as a ROS user gets it.

The package is copied into a temporary workspace (``<tmp>/src/cr_control``) and built there
with the virtual environment's colcon (pinned in requirements.txt), plain ``colcon build``
as a ROS user runs it (no --symlink-install). Every path colcon writes to is inside the
temporary workspace. Then: the executables, the share directory and the ament index marker
are where ``ros2 run`` / ``ros2 launch`` / ament_index_python look; and the installed
``adaptive_impedance`` and ``plant``, run with the environment ``install/setup.sh`` gives,
import the installed code, find the installed config through the ament index, take
``--ros-args --params-file`` and answer parameter queries.
"""

from __future__ import annotations

import ast
import os
import shutil
import signal
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

import pytest

from cr_control.schemes.registry import SCHEMES

REPO = Path(__file__).resolve().parents[1]
PACKAGE = "cr_control"
#: What a ROS package is made of; never .venv, sessions or build directories.
PACKAGE_FILES = ["package.xml", "setup.py", "setup.cfg"]
PACKAGE_DIRS = ["resource", "config", "cr_control", "cr_sim", "launch"]
TOOLS = ["plant", "recorder", "cr_session", "cr_analyze", "cr_benchmark", "cr_param"]
BUILD_TIMEOUT_S = 120
#: A node answers once its numba kernels are loaded (installed compiled from the source tree;
#: compiled at its first start, ~1 min on a loaded machine, where the source tree had none).
QUERY_DEADLINE_S = 180
STOP_TIMEOUT_S = 15


def _setup_py_schemes() -> list[str]:
    """The SCHEMES list of setup.py, read without running setup()."""
    tree = ast.parse((REPO / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "SCHEMES" for t in node.targets):
            return ast.literal_eval(node.value)
    raise AssertionError("setup.py defines no SCHEMES list")


def test_setup_py_schemes_are_the_registry():
    """One executable per registered scheme: a scheme forgotten in setup.py fails here."""
    schemes = _setup_py_schemes()
    assert len(schemes) == len(set(schemes)), f"duplicates in setup.py SCHEMES: {schemes}"
    assert sorted(schemes) == sorted(SCHEMES)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Path:
    """A colcon workspace holding a copy of the package, built with plain ``colcon build``.
    The copy carries the numba kernels the suite compiled (``__pycache__/*.nbi, *.nbc``;
    make test's warm-up), as a source tree where ``python -m cr_control.tools.warm_up`` ran:
    setup.py installs them beside the installed sources."""
    ws = tmp_path_factory.mktemp("colcon_ws")
    src = ws / "src" / PACKAGE
    src.mkdir(parents=True)
    for name in PACKAGE_FILES:
        shutil.copy2(REPO / name, src / name)
    for name in PACKAGE_DIRS:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, src / name,
                            ignore=shutil.ignore_patterns("*.pyc", "*.egg-info"))
    colcon = Path(sys.executable).parent / "colcon"
    assert colcon.is_file(), f"no colcon next to {sys.executable}: run `make venv` (requirements.txt)"
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["COLCON_HOME"] = str(ws / ".colcon")          # no user defaults (e.g. symlink-install)
    before = {name: (REPO / name).exists() for name in ("build", "install", "log")}
    start = time.monotonic()
    result = subprocess.run(
        [str(colcon), "--log-base", str(ws / "log"), "build",
         "--base-paths", str(ws / "src"), "--build-base", str(ws / "build"),
         "--install-base", str(ws / "install"), "--event-handlers", "console_direct+"],
        cwd=ws, env=env, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    print(f"colcon build: {time.monotonic() - start:.1f} s")
    assert result.returncode == 0, f"colcon build failed:\n{result.stdout[-5000:]}\n{result.stderr[-5000:]}"
    assert "Finished <<< cr_control" in result.stdout, result.stdout[-3000:]
    # Nothing written into the repository, nor into the package's source copy.
    assert {name: (REPO / name).exists() for name in before} == before
    assert not list(src.glob("*.egg-info")) and not (src / "build").exists()
    return ws


def _prefix(ws: Path) -> Path:
    return ws / "install" / PACKAGE


def _site_packages(ws: Path) -> Path:
    found = list((_prefix(ws) / "lib").glob("python3*/site-packages"))
    assert len(found) == 1, f"expected one site-packages dir, got {found}"
    return found[0]


def test_install_tree_has_what_ros_tools_look_for(workspace):
    prefix = _prefix(workspace)
    lib = prefix / "lib" / PACKAGE
    installed = {p.name for p in lib.iterdir()}
    expected = set(TOOLS) | set(SCHEMES)
    assert expected <= installed, f"missing executables in lib/{PACKAGE}: {sorted(expected - installed)}"
    for name in expected:
        assert os.access(lib / name, os.X_OK), f"lib/{PACKAGE}/{name} is not executable"
    share = prefix / "share" / PACKAGE
    assert (share / "package.xml").read_bytes() == (REPO / "package.xml").read_bytes()
    shipped = {p.name for p in (REPO / "config").iterdir() if p.suffix in (".yaml", ".urdf", ".json")}
    assert shipped and {p.name for p in (share / "config").iterdir()} >= shipped
    for name in shipped:
        assert (share / "config" / name).read_bytes() == (REPO / "config" / name).read_bytes()
    for scheme in SCHEMES:
        assert (share / "config" / f"{scheme}.yaml").is_file(), f"no installed params file for {scheme}"
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE).is_file()
    site = _site_packages(workspace)
    assert (site / "cr_control" / "__init__.py").is_file() and (site / "cr_sim" / "__init__.py").is_file()
    # The kernels compiled in the source tree are installed beside their sources.
    kernels = {p.relative_to(REPO) for d in ("cr_control", "cr_sim") for p in (REPO / d).rglob("*.nbi")}
    installed = {p.relative_to(site) for d in ("cr_control", "cr_sim") for p in (site / d).rglob("*.nbi")}
    assert kernels <= installed, f"not installed: {sorted(map(str, kernels - installed))[:5]}"
    # The nodes' Fast DDS profile (cr_control.core.ros_env.NODE_DDS_PROFILE) is package data.
    assert (site / "cr_control" / "core" / "fastdds_profile.xml").read_bytes() == (
        REPO / "cr_control" / "core" / "fastdds_profile.xml").read_bytes()


def _installed_env(ws: Path, ros_env: dict[str, str]) -> dict[str, str]:
    """``ros_env`` plus what sourcing ``install/setup.sh`` sets, plus the venv's site-packages."""
    out = subprocess.run(["sh", "-c", '. "$1/setup.sh" && env -0', "sh", str(ws / "install")],
                         env=ros_env, capture_output=True, timeout=30, check=True).stdout
    env = dict(item.split("=", 1) for item in out.decode().split("\0") if "=" in item)
    site = str(_site_packages(ws))
    assert env.get("PYTHONPATH", "").split(os.pathsep)[0] == site, env.get("PYTHONPATH")
    assert str(_prefix(ws)) in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep)
    env["PYTHONPATH"] = os.pathsep.join([env["PYTHONPATH"], sysconfig.get_paths()["purelib"]])
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = ros_env["ROS_AUTOMATIC_DISCOVERY_RANGE"]
    env["ROS_DOMAIN_ID"] = ros_env["ROS_DOMAIN_ID"]
    env["PYTHONFAULTHANDLER"] = "1"     # a hung node killed by SIGABRT logs where it hung
    return env


def _stop(procs: dict[str, tuple[subprocess.Popen, Path]]) -> dict[str, int]:
    """SIGINT to each, as Ctrl-C in `ros2 run`; log sizes at that moment. A node still
    running STOP_TIMEOUT_S later gets SIGABRT (its Python stacks go to its log), then SIGKILL."""
    sizes = {}
    for what, (proc, log) in procs.items():
        sizes[what] = log.stat().st_size
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    for proc, _ in procs.values():
        try:
            proc.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    return sizes


def _check_stopped(what: str, proc: subprocess.Popen, log: Path, size_at_sigint: int) -> None:
    """Ran without errors until SIGINT, then exited on its own within STOP_TIMEOUT_S."""
    text = log.read_bytes()
    before = text[:size_at_sigint].decode(errors="replace")
    after = text[size_at_sigint:].decode(errors="replace")
    for mark in ("Traceback", "[FATAL]", "[ERROR]"):
        assert mark not in before, f"{what} logged {mark} while running:\n{before[-3000:]}"
    assert proc.returncode not in (-signal.SIGABRT, -signal.SIGKILL), (
        f"{what} did not stop within {STOP_TIMEOUT_S} s of SIGINT; its log since:\n{after[-6000:]}")
    last = after.strip().splitlines()[-1] if after.strip() else ""
    assert proc.returncode == 0, f"{what} did not shut down cleanly (exit code {proc.returncode}): {last}"
    for mark in ("Traceback", "[FATAL]"):
        assert mark not in after, f"{what} logged {mark} while stopping:\n{after[-3000:]}"


def _query(cr_param: Path, env: dict[str, str], node: str, name: str, procs: dict) -> str:
    """``cr_param get node name`` (installed executable), retried until the node answers."""
    deadline = time.monotonic() + QUERY_DEADLINE_S
    while True:
        for what, (proc, log) in procs.items():
            assert proc.poll() is None, f"{what} exited ({proc.returncode}):\n{log.read_text()[-3000:]}"
        got = subprocess.run([str(cr_param), "get", node, name], env=env, capture_output=True,
                             text=True, timeout=QUERY_DEADLINE_S)
        if got.returncode == 0:
            return got.stdout
        if time.monotonic() > deadline:
            pytest.fail(f"no answer from {node} for {name}: {got.stdout}{got.stderr}")
        time.sleep(0.5)


@pytest.mark.ros
def test_installed_nodes_start_and_answer_parameter_queries(workspace, ros_env, tmp_path):
    env = _installed_env(workspace, ros_env)
    prefix = _prefix(workspace)
    lib = prefix / "lib" / PACKAGE
    share = prefix / "share" / PACKAGE

    # The installed code, and the installed config found through the ament index.
    probe = subprocess.run(
        [sys.executable, "-c", "import cr_control, cr_sim\n"
         "from cr_control.core.paths import config_dir\n"
         "print(cr_control.__file__); print(cr_sim.__file__); print(config_dir())"],
        cwd=workspace, env=env, capture_output=True, text=True, timeout=60)
    assert probe.returncode == 0, probe.stderr
    control_file, sim_file, config = probe.stdout.split()
    site = _site_packages(workspace)
    assert Path(control_file).is_relative_to(site) and Path(sim_file).is_relative_to(site), probe.stdout
    assert Path(config).resolve() == (share / "config").resolve()

    # As `ros2 run cr_control adaptive_impedance --ros-args --params-file ...` would start it.
    override = tmp_path / "override.yaml"
    override.write_text("adaptive_impedance:\n  ros__parameters:\n    Q_c: [7.0, 7.0]\n")
    commands = {
        "adaptive_impedance": [str(lib / "adaptive_impedance"), "--ros-args", "--params-file",
                               str(share / "config" / "adaptive_impedance.yaml"),
                               "--params-file", str(override)],
        # Lockstep: this test is about the install tree, not about holding 1 kHz on a busy
        # machine (a real-time plant would rightly brake when a loaded CI starves the loop).
        "plant": [str(lib / "plant"), "--ros-args", "--params-file",
                  str(share / "config" / "plant_compliant_plane.yaml"), "-p", "mode:=lockstep"],
    }
    procs: dict[str, tuple[subprocess.Popen, Path]] = {}
    try:
        for what, cmd in commands.items():
            log = tmp_path / f"{what}.log"
            with log.open("w") as out:
                procs[what] = (subprocess.Popen(cmd, cwd=workspace, env=env, stdout=out,
                                                stderr=subprocess.STDOUT), log)
        cr_param = lib / "cr_param"
        assert "Q_c: [7.0, 7.0]" in _query(cr_param, env, "/adaptive_impedance", "Q_c", procs)
        assert "rate_hz: 1000.0" in _query(cr_param, env, "/plant", "rate_hz", procs)
        # Both still running, then stopped as a user would.
        for what, (proc, log) in procs.items():
            assert proc.poll() is None, f"{what} exited ({proc.returncode}):\n{log.read_text()[-3000:]}"
    finally:
        sizes = _stop(procs)
    for what, (proc, log) in procs.items():
        _check_stopped(what, proc, log, sizes[what])
