"""cr_param: list, get and set a node's parameters live, where there is no ``ros2 param``.

Calls the same standard rcl_interfaces services ``ros2 param`` calls, so it works with
any ROS 2 node. Runs on $ROS_DOMAIN_ID (the session runner prints the one it uses) with
localhost discovery unless set otherwise. The node is named as ``ros2 param`` takes it:
``/ns/name``, ``name`` (``/name``) or ``ns/name``; a name ROS would not accept is refused
before anything starts. Values are YAML as ROS params files read it (``1e12`` is a
number; no aliases). A node that does not answer within ``--timeout`` seconds (default 3,
at most 3600) counts as not found. Exit status: 0 done, 1 refused by the node, 2 usage or
connection error (invalid node name, unknown parameter, unreadable value, node not found
or not answering).

    cr_param list /adaptive_impedance
    cr_param get /adaptive_impedance Q_c
    cr_param set /adaptive_impedance Q_c "[50.0, 50.0]" --domain-id 12
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import yaml

from cr_control.core import ros_yaml
from cr_control.core.parameters import _shown as shown  # a value in a message, cut to 80 chars
from cr_control.core.ros_env import domain_id_arg, isolate_this_process, use_visitor_dds_profile

#: Default of ``--timeout``: how long to wait for the node to appear and for each answer (s).
TIMEOUT_S = 3.0
#: Longest ``--timeout`` (s) of the tools that wait for a node: more is a typo, not a wait.
MAX_TIMEOUT_S = 3600.0


def full_node_name(text: str) -> str:
    """The absolute name (``/ns/name``) of the node ``text`` names, as ``ros2 param`` reads
    it (a leading ``/`` is added if missing); ValueError saying why if ROS would not take it
    (empty, a space, ``//``, a trailing ``/``, a leading digit, non-ASCII, too long, ...)."""
    # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
    from rclpy.exceptions import NameValidationException
    from rclpy.validate_full_topic_name import validate_full_topic_name
    from rclpy.validate_namespace import validate_namespace
    from rclpy.validate_node_name import validate_node_name

    full = text if text.startswith("/") else f"/{text}"
    namespace, _, name = full.rpartition("/")
    longest = f"{full}/set_parameters_atomically"   # of its parameter services' names
    try:
        if not text:
            raise ValueError("it is empty")
        if "//" in full:
            raise ValueError("it contains '//'")
        if full.endswith("/"):
            raise ValueError("it ends with '/'")
        validate_namespace(namespace or "/")
        validate_node_name(name)
        validate_full_topic_name(longest)
    except ValueError as exc:
        reason = str(exc)
    except NameValidationException as exc:
        # rclpy's message: "Invalid node name: <reason>:", then the name and a caret
        reason = str(exc).splitlines()[0].rstrip(":").partition(": ")[2]
        if "topic" in reason:
            reason = f"{reason} (service name {longest})"
    else:
        return full
    raise ValueError(f"invalid node name {text!r}: {reason}")


def timeout_seconds(text: str) -> float:
    """argparse ``type`` of every ``--timeout`` (cr_param, cr_lifecycle, cr_identify_tool): a
    number of seconds in (0, MAX_TIMEOUT_S]; NaN, infinite, zero, negative or larger is
    refused (a NaN deadline is never reached: the tool would wait for ever)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0.0 < value <= MAX_TIMEOUT_S:
        raise argparse.ArgumentTypeError(
            f"must be a number of seconds > 0 and <= {MAX_TIMEOUT_S:g}, not {shown(text)}")
    return value


def wait_for_service(node, executor, client, timeout_s: float, what: str) -> None:
    """Spin until ``client``'s service is matched; TimeoutError after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not client.service_is_ready():
        if time.monotonic() > deadline:
            raise TimeoutError(f"no node {client.srv_name.rpartition('/')[0]} on ROS_DOMAIN_ID "
                               f"{node.context.get_domain_id()} ({what} did not appear "
                               f"within {timeout_s:g} s; see --timeout)")
        executor.spin_once(timeout_sec=0.02)


def call_service(node, executor, srv_type, service: str, request, timeout_s: float,
                 what: str = "its parameter services", client=None):
    """``request`` to ``service`` (through ``client`` if given, else a new one); TimeoutError
    if the service does not appear or does not answer within ``timeout_s`` (each); ``what``
    names the node's services in that message."""
    client = client or node.create_client(srv_type, service)
    wait_for_service(node, executor, client, timeout_s, what)
    future = client.call_async(request)
    deadline = time.monotonic() + timeout_s
    while not future.done():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{service} did not answer within {timeout_s:g} s (see --timeout)")
        executor.spin_once(timeout_sec=0.02)
    return future.result()


def _parse_value(text: str):
    """The command-line value as YAML (ValueError naming the problem)."""
    try:
        return ros_yaml.load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"value {shown(text)} is not valid YAML: "
                         f"{ros_yaml.describe_error(exc)}") from None


def run(args: argparse.Namespace) -> int:
    """Carry out one list/get/set command; print the outcome; exit code."""
    # lazy: ROS is loaded only when the command talks to a node (cr_control.tools)
    import rclpy
    from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter, parameter_value_to_python

    # lazy: loaded when the command runs (cr_control.tools)
    from cr_control.nodes.ros_parameters import coerce, refuse_unknown

    target = args.node
    rclpy.init(args=[sys.argv[0]])   # not our command line: it is no --ros-args
    node = rclpy.create_node("cr_param")
    executor = SingleThreadedExecutor()
    executor.add_node(node)

    def call(srv_type, service: str, request):
        return call_service(node, executor, srv_type, f"{target}/{service}", request, args.timeout)

    def names() -> list[str]:
        return sorted(call(ListParameters, "list_parameters", ListParameters.Request()).result.names)

    try:
        if args.command == "list":
            print("\n".join(names()))
            return 0
        value = _parse_value(args.value) if args.command == "set" else None
        described = call(DescribeParameters, "describe_parameters",
                         DescribeParameters.Request(names=[args.name])).descriptors
        if not described:  # what rclpy answers for a parameter the node does not have
            refuse_unknown(target, [args.name], names())
        if args.command == "get":
            result = call(GetParameters, "get_parameters", GetParameters.Request(names=[args.name]))
            print(f"{args.name}: {parameter_value_to_python(result.values[0])}")
            return 0
        value = coerce(value, described[0].type)
        try:
            msg = Parameter(args.name, value=value).to_parameter_msg()
        except TypeError:
            raise ValueError(f"{shown(args.value)} cannot be a ROS parameter value") from None
        result = call(SetParameters, "set_parameters", SetParameters.Request(parameters=[msg])).results[0]
        if result.successful:
            print(f"set {args.name} = {value}")
            return 0
        print(f"refused: {result.reason}", file=sys.stderr)
        return 1
    except (TimeoutError, ValueError) as exc:  # ParameterError is a ValueError
        print(f"cr_param: {exc}", file=sys.stderr)
        return 2
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    p = argparse.ArgumentParser(prog="cr_param", description=__doc__.split("\n\n")[0])

    def add_options(parser: argparse.ArgumentParser, default) -> None:
        # On the main parser and on each command, so they may come before or after it
        # (a command's own defaults are suppressed: they would hide the main parser's).
        parser.add_argument("--domain-id", type=domain_id_arg, default=default(None),
                            help="ROS_DOMAIN_ID of the session (default: $ROS_DOMAIN_ID)")
        parser.add_argument("--timeout", type=timeout_seconds, default=default(TIMEOUT_S),
                            metavar="S", help="wait at most S seconds for the node and for each "
                                              f"answer (default {TIMEOUT_S:g})")

    add_options(p, lambda value: value)
    sub = p.add_subparsers(dest="command", required=True)
    commands = {name: sub.add_parser(name, help=text) for name, text in (
        ("list", "names of a node's parameters"), ("get", "a parameter's value"),
        ("set", "change a parameter (refused values leave the old one)"))}
    for name, command in commands.items():
        command.add_argument("node", help="node name as ros2 param takes it: /ns/name, name or ns/name")
        if name != "list":
            command.add_argument("name", help="parameter name")
        add_options(command, lambda value: argparse.SUPPRESS)
    commands["set"].add_argument("value", help="YAML value, e.g. 2.0, 1e12 or '[50.0, 50.0]'")
    args = p.parse_args(argv)
    try:
        args.node = full_node_name(args.node)
    except ValueError as exc:
        print(f"cr_param: {exc}", file=sys.stderr)
        return 2
    isolate_this_process(args.domain_id)
    use_visitor_dds_profile()   # never sent to through shared memory: no join stall
    try:
        return run(args)
    except KeyboardInterrupt:
        print("cr_param: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
