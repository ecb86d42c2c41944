"""Every ROS test is isolated: localhost-only discovery and a domain id of its own.

Domain ids come from :func:`ros_probe.next_domain`, which holds them machine-wide
(cr_control.core.ros_env locks) for the test, or the module for module-scoped fixtures.

Two tiers. A test that starts ROS or a Ray cluster is marked ``ros``: it calls rclpy.init
(also through ros_probe.RosProbe, plant_harness's ``make_node`` or a node made in the
test), starts a process of our nodes, of cr_session or of a tool that talks to nodes
(cr_param, cr_lifecycle, cr_fuzz, cr_identify_tool, the benchmark), or starts Ray (the
sweep engine, cr_reproduce). Mark the test with ``@pytest.mark.ros``, or the whole module
with ``pytestmark = pytest.mark.ros`` when every test in it does. ``make test-fast`` runs
the rest (``pytest -m "not ros"``, under 2 minutes); ``make test`` and CI run both. An
unmarked test that calls rclpy.init fails at once, saying so.
"""

import os

import pytest
from plant_harness import make_node  # noqa: F401 - a fixture for every test module
from rclpy.context import Context
from ros_probe import domains_taken, next_domain, release_domains

from cr_control.core.ros_env import isolated_env, use_node_dds_profile
from cr_control.nodes.discovery_settle import SETTLE_VARIABLE

# Tests that call rclpy.init in this process inherit these; the id is held for the run.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ["ROS_DOMAIN_ID"] = str(next_domain())
os.environ.setdefault("MPLBACKEND", "Agg")
use_node_dds_profile()   # nodes made in this process run as they do in their executables
# Real-time controllers of the suite subscribe to the states at once: the wait of
# cr_control/nodes/discovery_settle.py (4 s a start, minutes over the suite) is tested in
# test_discovery_settle.py.
os.environ.setdefault(SETTLE_VARIABLE, "0")


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "ros: starts ROS or a Ray cluster (rclpy.init, a node, cr_session, a ROS tool, "
                   "Ray); make test-fast leaves these out (-m 'not ros')")


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
    deterministic, so every test reading it sees the numbers CI and docs/results.md see."""
    from cr_control.experiments import reproduce

    out = tmp_path_factory.mktemp("reproduce_quick")
    assert reproduce.main(["--quick", "--out", str(out)]) == 0
    return out
