"""Message definitions and QoS as rosbag2 writes them into an MCAP file: the full ``.msg``
(or ``.idl``) text of a type with its dependencies concatenated (rosbag2's
``LocalMessageDefinitionSource`` layout), the offered QoS profiles as rosbag2's YAML, the
QoS a recorder requests from the offers, and a type's Python class. No node here.
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

#: Reader history of the recorder's subscriptions: KEEP_ALL, so that a chunk compression
#: or a scheduling hiccup on a busy machine never overwrites messages that arrived but
#: were not yet taken. Fast DDS bounds it (5000 samples per reader, its default resource
#: limit, measured) and, when it is full, stops acknowledging: a lockstep plant, which
#: waits for its readers' acknowledgements, then waits for the recorder (plant_node.py).
SUBSCRIPTION_HISTORY = HistoryPolicy.KEEP_ALL
ROSBAG2_METADATA_VERSION = 9
#: Node name of an endpoint whose node is not (yet) known to the graph.
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"
_DELIMITER = "=" * 80 + "\n"
_INFINITE_NS = 9_223_372_036_854_775_807


# -- message definitions (rosbag2's LocalMessageDefinitionSource) ------------------------

# Field types of a .msg ("foo_msgs/Bar" in "foo_msgs/Bar[] bar") and includes of an .idl.
_MSG_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_IDL_INCLUDE = re.compile(r"(?:^|\n)#include\s+(?:\"|<)([a-zA-Z0-9_/]+)\.idl(?:\"|>)")
_PRIMITIVES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
})


class DefinitionNotFoundError(LookupError):
    """No .msg/.idl file for a message type was found."""


@functools.cache
def _share_dirs(package: str) -> tuple[Path, ...]:
    """Candidate ``share/<package>`` directories, most likely first."""
    candidates: list[Path] = []
    spec = importlib.util.find_spec(package)
    if spec is not None and spec.origin:
        # <prefix>/lib/pythonX.Y/site-packages/<package>/__init__.py (or local/lib/...).
        for parent in Path(spec.origin).resolve().parents[1:6]:
            candidates.append(parent / "share" / package)
    candidates.append(Path(sys.prefix) / "share" / package)
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / package)
    return tuple(dict.fromkeys(c for c in candidates if c.is_dir()))


def _split_type(type_name: str) -> tuple[str, str, str]:
    """(package, namespace, name) of ``pkg/Type`` or ``pkg/msg/Type``."""
    parts = type_name.split("/")
    if len(parts) == 2:
        return parts[0], "msg", parts[1]
    if len(parts) == 3:
        return parts[0], parts[1], parts[2]
    raise ValueError(f"invalid message type name {type_name!r}")


@functools.cache
def _definition_file_text(type_name: str, extension: str) -> str:
    package, namespace, name = _split_type(type_name)
    for share in _share_dirs(package):
        path = share / namespace / f"{name}{extension}"
        if path.is_file():
            return path.read_text(encoding="utf-8")
    raise DefinitionNotFoundError(type_name)


def _dependencies(text: str, package: str, idl: bool) -> list[str]:
    """Types a definition refers to, sorted as rosbag2's std::set orders them."""
    if idl:
        return sorted(set(_IDL_INCLUDE.findall(text)))
    found = set()
    for type_name in _MSG_FIELD_TYPE.findall(text):
        if type_name in _PRIMITIVES:
            continue
        found.add(type_name if "/" in type_name else f"{package}/{type_name}")
    return sorted(found)


@functools.cache
def message_definition(type_name: str) -> tuple[str, str]:
    """(schema encoding, full definition text) of ``type_name`` as rosbag2 stores it.

    ``ros2msg``: the type's ``.msg`` text, then each dependency, recursively and once,
    after a line of 80 ``=`` and a line ``MSG: <type>``. Falls back to ``ros2idl`` when
    there is no ``.msg``; raises :class:`DefinitionNotFoundError` when neither exists.
    """
    def full_text(root: str, extension: str, tag: str) -> str:
        seen: set[str] = set()

        def append(name: str, depth: int) -> str:
            if depth <= 0:
                raise RecursionError(f"definition of {root} nests too deeply")
            text = _definition_file_text(name, extension)
            result = text
            for dep in _dependencies(text, _split_type(name)[0], idl=extension == ".idl"):
                if dep not in seen:
                    seen.add(dep)
                    result += "\n" + _DELIMITER + f"{tag}: {dep}\n" + append(dep, depth - 1)
            return result

        return append(root, 50)

    try:
        return "ros2msg", full_text(type_name, ".msg", "MSG")
    except DefinitionNotFoundError:
        text = full_text(type_name, ".idl", "IDL")
        return "ros2idl", _DELIMITER + f"IDL: {type_name}\n" + text


# -- QoS as rosbag2 serializes it ------------------------------------------------------

def _duration_yaml(nanoseconds: int) -> dict[str, int]:
    return {"sec": nanoseconds // 1_000_000_000, "nsec": nanoseconds % 1_000_000_000}


def qos_profile_dict(qos: QoSProfile) -> dict[str, Any]:
    """One offered QoS profile in rosbag2's metadata form (version 9: policy names)."""
    return {
        "history": qos.history.name.lower(),
        "depth": int(qos.depth),
        "reliability": qos.reliability.name.lower(),
        "durability": qos.durability.name.lower(),
        "deadline": _duration_yaml(qos.deadline.nanoseconds),
        "lifespan": _duration_yaml(qos.lifespan.nanoseconds),
        "liveliness": qos.liveliness.name.lower(),
        "liveliness_lease_duration": _duration_yaml(qos.liveliness_lease_duration.nanoseconds),
        "avoid_ros_namespace_conventions": bool(qos.avoid_ros_namespace_conventions),
    }


class PlainDumper(yaml.SafeDumper):
    """A safe YAML dumper that writes every value out, never an anchor and alias: rosbag2
    writes one entry per publisher even when they are equal, and readers (ours among them)
    refuse aliases."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def qos_profiles_yaml(profiles: Sequence[dict[str, Any]]) -> str:
    """The ``offered_qos_profiles`` channel metadata string."""
    return yaml.dump(list(profiles), Dumper=PlainDumper, sort_keys=False, default_flow_style=False)


def request_qos(offered: Sequence[QoSProfile]) -> QoSProfile:
    """A subscription QoS that matches every offer (rosbag2's adapt_request_to_offers)."""
    reliable = bool(offered) and all(
        q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
    transient = bool(offered) and all(
        q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
    return QoSProfile(
        history=SUBSCRIPTION_HISTORY,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE)


def has_header(msg_class: type) -> bool:
    fields = iter(msg_class.get_fields_and_field_types().items())
    first = next(fields, None)
    return first is not None and first[1] in ("std_msgs/Header", "std_msgs/msg/Header")


def import_message(type_name: str) -> type:
    """The Python class of ``pkg/msg/Type``."""
    package, namespace, name = _split_type(type_name)
    return getattr(importlib.import_module(f"{package}.{namespace}"), name)
