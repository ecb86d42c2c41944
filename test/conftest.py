"""Every ROS test is isolated: localhost-only discovery and a domain id of its own.

Domain ids come from :func:`ros_probe.next_domain`, which holds them machine-wide
(cr_control.core.ros_env locks) for the test, or the module for module-scoped fixtures.

Two tiers, run on both cores (pytest-xdist: ``-n 3`` for the whole suite, whose ROS tests wait
on processes a quarter of the time; ``-n 2`` for the fast tier). A test that starts ROS or a
Ray cluster is marked ``ros``: it calls rclpy.init
(also through ros_probe.RosProbe, plant_harness's ``make_node`` or a node made in the
test), starts a process of our nodes, of cr_session or of a tool that talks to nodes
(cr_param, cr_lifecycle, cr_fuzz, cr_identify_tool, the benchmark), or starts Ray (the
sweep engine, cr_reproduce). Mark the test with ``@pytest.mark.ros``, or the whole module
with ``pytestmark = pytest.mark.ros`` when every test in it does. ``make test-fast`` runs
the rest (``pytest -m "not ros and not slow"``, under 2 minutes); ``make test`` and CI run
all. A long offline study (many closed-loop runs, tens of seconds) is marked ``slow``: the
fast tier leaves it to the full suite. An unmarked test that calls rclpy.init fails at once,
saying so.

In parallel, every module runs whole on one worker (its module fixtures made once); the
modules that start a Ray cluster share one worker (:data:`RAY_MODULES`: two clusters at once
would contend for the head's ports), and the long modules are handed out first
(:data:`LONG_MODULES`) so that no worker is left with one at the end. Each worker holds ROS
domains of its own (:func:`ros_probe.next_domain`, machine-wide locks).
"""

import fcntl
import os
import shutil
import signal

import pytest
from plant_harness import make_node  # noqa: F401 - a fixture for every test module
from rclpy.context import Context
from ros_probe import domains_taken, next_domain, release_domains

from cr_control.core.ros_env import isolated_env, use_node_dds_profile
from cr_control.nodes.discovery_settle import SETTLE_VARIABLE

# Tests send Ctrl-C to the processes they start. A suite started where SIGINT is ignored (a
# background job of a non-interactive shell) would pass that on to every one of them, and no
# Ctrl-C would reach them: the default comes back here, for this process and its children.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# Tests that call rclpy.init in this process inherit these; the id is held for the run.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ["ROS_DOMAIN_ID"] = str(next_domain())
os.environ.setdefault("MPLBACKEND", "Agg")
use_node_dds_profile()   # nodes made in this process run as they do in their executables
# Real-time controllers of the suite subscribe to the states at once: the wait of
# cr_control/nodes/discovery_settle.py (4 s a start, minutes over the suite) is tested in
# test_discovery_settle.py.
os.environ.setdefault(SETTLE_VARIABLE, "0")


#: Modules that start a Ray cluster (the sweep engine, cr_reproduce --quick): one worker.
RAY_MODULES = ("test_readme.py", "test_results_tables.py", "test_sweep.py", "test_sweep_cluster.py")
#: The longest modules, handed out first, longest first (their mean worker time in two
#: fresh-clone runs of the suite, 2026-11-29: 483 s for test_readme's Ray group down to 22 s),
#: so that no worker is left with a long one at the end; the rest follow in name order.
LONG_MODULES = tuple(f"test_{name}.py" for name in (
    "readme", "robots", "gain_matrix", "admittance_outer_loop", "chapter4_ros", "sigint",
    "chapter6_ros", "ros_session", "fuzz_inputs", "hostile_targets", "safety_plant",
    "clean_errors", "reflex", "lifecycle", "real_robots", "target_bounds", "cli_guards",
    "identify_ros", "chapter5", "lockstep_lossless", "benchmark", "contact_guard", "intruder",
    "analysis_robot", "colcon"))


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "ros: starts ROS or a Ray cluster (rclpy.init, a node, cr_session, a ROS tool, "
                   "Ray); make test-fast leaves these out (-m 'not ros')")
    config.addinivalue_line(
        "markers", "slow: a long offline study (tens of seconds); make test runs it, make "
                   "test-fast leaves it out (-m 'not slow')")


#: Long matrices (parametrized closed-loop runs, commands or files, a second or more each in
#: all): the first cases of each stay in the fast tier (a sample every edit runs), the rest
#: are ``slow`` and run in the full suite.
STUDIES = {
    "test_robots.py::test_wiping_holds_the_force_on_the_path": 2,
    "test_robots.py::test_wiping_a_stiff_table": 1,
    "test_robots.py::test_wiping_at_three_times_the_drivers_delay": 2,
    "test_robots.py::test_wiping_through_late_bursts": 4,
    "test_gain_matrix.py::test_a_gain_at_its_accepted_extreme_holds_the_task": 3,
    "test_hostile_targets.py::test_no_target_wrench_sequence_winds_a_law_up": 2,
    "test_hostile_targets.py::test_zero_ft_every_0_2_s_while_pressing_10_n_leaves_the_true_force_alone": 1,
    "test_hostile_targets.py::test_a_target_pose_out_of_reach_never_needs_a_reflex": 2,
    "test_admittance_outer_loop.py::test_wiping_through_the_outer_loop": 2,
    "test_admittance_outer_loop.py::test_a_stiff_table_is_held_after_the_guarded_approach": 1,
    "test_admittance_outer_loop.py::test_nothing_drifts_over_a_minute_of_wiping": 0,
    "test_admittance_outer_loop.py::test_a_tenfold_gain_step_moves_the_command_little": 2,
    "test_admittance_outer_loop.py::test_hostile_inputs_never_make_the_command_jump": 1,
    "test_hostile_targets.py::test_a_1e6_n_target_wrench_is_scaled_to_max_target_force": 1,
    "test_hostile_targets.py::test_sign_flips_at_every_cycle_of_a_500_hz_robot": 1,
    "test_target_bounds.py::test_streamed_targets_anywhere_leave_the_force_to_the_force_loop": 2,
    "test_target_bounds.py::test_single_targets_anywhere_leave_the_force_to_the_force_loop": 1,
    "test_target_bounds.py::test_a_target_streamed_along_the_table_until_the_reach": 1,
    "test_real_robots.py::test_a_guarded_start_from_above_the_table": 2,
    "test_real_robots.py::test_a_wrong_model_costs_little": 1,
    "test_real_robots.py::test_a_gravity_mismatch_is_caught_in_the_first_second": 2,
    # matrices of a command or a file per case (a process or a regeneration each)
    "test_fuzz_inputs.py::test_every_hostile_input_is_refused_in_one_line": 4,
    "test_parameters.py::test_shipped_robot_configs_are_the_generated_wiping_task": 4,
}


def _module(nodeid: str) -> str:
    return nodeid.split("::")[0].rpartition("/")[2]


def pytest_collection_modifyitems(config, items):
    """The studies' slow cases marked (before ``-m`` deselects); long modules first."""
    seen: dict[str, int] = {}
    for item in items:
        study = f"{_module(item.nodeid)}::{item.originalname}"
        if study in STUDIES:
            seen[study] = seen.get(study, 0) + 1
            if seen[study] > STUDIES[study]:
                item.add_marker(pytest.mark.slow)
    rank = {name: i for i, name in enumerate(LONG_MODULES)}
    items.sort(key=lambda item: rank.get(_module(item.nodeid), len(rank)))  # stable: order kept


def pytest_xdist_make_scheduler(config, log):
    """Whole modules to a worker (their module fixtures made once), the Ray modules all to
    one, handed out in collection order (long modules first): xdist's loadscope with these
    scopes. (Its ``xdist_group`` marks do not group under pytest 9, which no longer reads
    the test id xdist rewrites for them.)"""
    from xdist.scheduler import LoadScopeScheduling

    class ModuleScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = _module(nodeid)
            return "ray" if module in RAY_MODULES else nodeid.split("::")[0]

    config.option.loadscopereorder = False
    return ModuleScheduling(config, log)


#: Whether the running test may start ROS (its ``ros`` mark), set before its fixtures.
_ros_allowed = True
_context_init = Context.init


def _init_if_marked(self, *args, **kwargs):
    if not _ros_allowed:
        raise RuntimeError("this test starts ROS (rclpy.init) but is not marked: add "
                           "@pytest.mark.ros (see test/conftest.py)")
    return _context_init(self, *args, **kwargs)


Context.init = _init_if_marked   # rclpy.init, RosProbe and make_node all come through here


def pytest_runtest_setup(item):
    global _ros_allowed
    _ros_allowed = item.get_closest_marker("ros") is not None


@pytest.fixture(autouse=True, scope="module")
def _module_domains():
    """Domains taken by module-scoped fixtures are released after the module."""
    mark = domains_taken()
    yield
    release_domains(mark)


@pytest.fixture(autouse=True)
def _test_domains():
    """Domains taken during a test (and its function-scoped fixtures) are released after it."""
    mark = domains_taken()
    yield
    release_domains(mark)


@pytest.fixture
def ros_env() -> dict[str, str]:
    """Environment for subprocesses of one test: localhost discovery, a fresh domain id."""
    return isolated_env(domain_id=next_domain())


@pytest.fixture(scope="session")
def reproduce_quick(tmp_path_factory):
    """DIR of one ``cr_reproduce --quick`` run (report.html, claims.json) for the session:
    deterministic, so every test reading it sees the numbers CI and docs/results.md see.
    Made once for all workers (a lock in their shared temporary directory)."""
    from cr_control.experiments import reproduce

    shared = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = shared.parent                  # the workers' common directory
    out, done = shared / "reproduce_quick", shared / "reproduce_quick.done"
    with open(shared / "reproduce_quick.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            shutil.rmtree(out, ignore_errors=True)
            assert reproduce.main(["--quick", "--out", str(out)]) == 0
            done.touch()
    return out
