"""cr_param: list, get and set a node's parameters live, where there is no ``ros2 param``.

Calls the same standard rcl_interfaces services ``ros2 param`` calls, so it works with
any ROS 2 node. Runs on $ROS_DOMAIN_ID (the session runner prints the one it uses) with
localhost discovery unless set otherwise.

    cr_param list /adaptive_impedance
    cr_param get /adaptive_impedance Q_c
    cr_param set /adaptive_impedance Q_c "[50.0, 50.0]" --domain-id 12
"""

from __future__ import annotations

import argparse
import sys
import time

import yaml

from cr_control.core.ros_env import isolate_this_process

TIMEOUT_S = 10.0


def _coerce(value, ros_type: int):
    """Make a YAML value fit the declared type (``5`` for a double, ``[1, 2]`` for doubles)."""
    from rcl_interfaces.msg import ParameterType

    if ros_type == ParameterType.PARAMETER_DOUBLE and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if ros_type == ParameterType.PARAMETER_DOUBLE_ARRAY and isinstance(value, list):
        return [float(v) if isinstance(v, int) and not isinstance(v, bool) else v for v in value]
    return value


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


def run(args: argparse.Namespace) -> int:
    """Carry out one list/get/set command; print the outcome; exit code."""
    import rclpy
    from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter, parameter_value_to_python

    target = "/" + args.node.strip("/")
    rclpy.init()
    node = rclpy.create_node("cr_param")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        if args.command == "list":
            result = _call(node, executor, ListParameters, f"{target}/list_parameters",
                           ListParameters.Request())
            print("\n".join(sorted(result.result.names)))
            return 0
        if args.command == "get":
            result = _call(node, executor, GetParameters, f"{target}/get_parameters",
                           GetParameters.Request(names=[args.name]))
            print(f"{args.name}: {parameter_value_to_python(result.values[0])}")
            return 0
        described = _call(node, executor, DescribeParameters, f"{target}/describe_parameters",
                          DescribeParameters.Request(names=[args.name])).descriptors[0]
        value = _coerce(yaml.safe_load(args.value), described.type)
        msg = Parameter(args.name, value=value).to_parameter_msg()
        result = _call(node, executor, SetParameters, f"{target}/set_parameters",
                       SetParameters.Request(parameters=[msg])).results[0]
        if result.successful:
            print(f"set {args.name} = {value}")
            return 0
        print(f"refused: {result.reason}", file=sys.stderr)
        return 1
    except (TimeoutError, TypeError, yaml.YAMLError) as exc:
        print(f"cr_param: {exc}", file=sys.stderr)
        return 2
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    p = argparse.ArgumentParser(prog="cr_param", description=__doc__.split("\n\n")[0])
    p.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID of the session (default: $ROS_DOMAIN_ID)")
    sub = p.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="names of a node's parameters").add_argument("node")
    get = sub.add_parser("get", help="a parameter's value")
    get.add_argument("node")
    get.add_argument("name")
    set_ = sub.add_parser("set", help="change a parameter (refused values leave the old one)")
    set_.add_argument("node")
    set_.add_argument("name")
    set_.add_argument("value", help="YAML value, e.g. 2.0 or '[50.0, 50.0]'")
    args = p.parse_args(argv)
    isolate_this_process(args.domain_id)
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
