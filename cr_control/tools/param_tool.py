"""cr_param: list, get and set a node's parameters live, where there is no ``ros2 param``.

Calls the same standard rcl_interfaces services ``ros2 param`` calls, so it works with
any ROS 2 node. Runs on $ROS_DOMAIN_ID (the session runner prints the one it uses) with
localhost discovery unless set otherwise. Values are YAML as ROS params files read it
(``1e12`` is a number). Exit status: 0 done, 1 refused by the node, 2 usage or
connection error (unknown parameter, unreadable value, node not found).

    cr_param list /adaptive_impedance
    cr_param get /adaptive_impedance Q_c
    cr_param set /adaptive_impedance Q_c "[50.0, 50.0]" --domain-id 12
"""

from __future__ import annotations

import argparse
import sys
import time

import yaml

from cr_control.core import ros_yaml
from cr_control.core.ros_env import domain_id_arg, isolate_this_process

TIMEOUT_S = 10.0


def _call(node, executor, srv_type, service: str, request):
    client = node.create_client(srv_type, service)
    deadline = time.monotonic() + TIMEOUT_S
    while not client.service_is_ready():
        if time.monotonic() > deadline:
            raise TimeoutError(f"no service {service}: is the node running on this ROS_DOMAIN_ID?")
        executor.spin_once(timeout_sec=0.05)
    future = client.call_async(request)
    while not future.done():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{service} did not answer")
        executor.spin_once(timeout_sec=0.05)
    return future.result()


def _parse_value(text: str):
    """The command-line value as YAML (ValueError naming the problem)."""
    try:
        return ros_yaml.load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"value {text!r} is not valid YAML: {ros_yaml.describe_error(exc)}") from None


def run(args: argparse.Namespace) -> int:
    """Carry out one list/get/set command; print the outcome; exit code."""
    import rclpy
    from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter, parameter_value_to_python

    from cr_control.nodes.ros_parameters import coerce, refuse_unknown

    target = "/" + args.node.strip("/")
    rclpy.init()
    node = rclpy.create_node("cr_param")
    executor = SingleThreadedExecutor()
    executor.add_node(node)

    def call(srv_type, service: str, request):
        return _call(node, executor, srv_type, f"{target}/{service}", request)

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
            raise ValueError(f"{args.value!r} cannot be a ROS parameter value") from None
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
    p.add_argument("--domain-id", type=domain_id_arg,
                   help="ROS_DOMAIN_ID of the session (default: $ROS_DOMAIN_ID)")
    sub = p.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="names of a node's parameters").add_argument("node")
    get = sub.add_parser("get", help="a parameter's value")
    get.add_argument("node")
    get.add_argument("name")
    set_ = sub.add_parser("set", help="change a parameter (refused values leave the old one)")
    set_.add_argument("node")
    set_.add_argument("name")
    set_.add_argument("value", help="YAML value, e.g. 2.0, 1e12 or '[50.0, 50.0]'")
    args = p.parse_args(argv)
    isolate_this_process(args.domain_id)
    try:
        return run(args)
    except KeyboardInterrupt:
        print("cr_param: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
