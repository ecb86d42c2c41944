"""A raw subscription whose callback also gets the sender: ``callback(data, gid)`` with the
serialized message (bytes) and the publishing endpoint's GID (16 bytes), for a node that
must tell its publishers apart (the plant's one commander at a time).

rclpy 7.1.6 (Jazzy) hands no publisher GID to Python: a two-argument subscription
callback gets ``{source_timestamp, received_timestamp, publication_sequence_number,
reception_sequence_number}`` only (rclpy added ``publisher_gid`` in 2025, ros2/rclpy#1466,
after Jazzy's last release here), and its EventsExecutor passes that ``(msg, info)``
pair to such a callback as one tuple argument. rcl has it: ``rcl_take_serialized_message``
fills an ``rmw_message_info_t`` with ``publisher_gid``. So the subscription here is an
rcl subscription made by rclpy's own binding but taken by this module through ctypes
(``librcl.so``, the same library rclpy loaded), wrapped in a
:class:`rclpy.waitable.Waitable` that any executor (EventsExecutor included) drives:
the message is taken and the callback run in ``take_data``, on the executor's thread.

The buffer is reused (rmw grows it when a message is larger): the callback gets the
bytes only when the message is at most ``max_bytes`` long; a longer one is handed over
as ``data=None`` with its length (``callback(None, gid, length)``), never copied to Python.

The layouts below are those of rmw/types.h and rcutils of Jazzy (``RMW_GID_STORAGE_SIZE``
16): every take checks that the GID names this rmw (``implementation_identifier``), and
raises if not rather than compare garbage. :func:`available` says whether rcl's library
can be called at all; callers fall back to a plain subscription if not.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable

from rclpy import get_rmw_implementation_identifier
from rclpy.callback_groups import CallbackGroup
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.type_support import check_is_valid_msg_type
from rclpy.waitable import NumberOfEntities, Waitable

#: rmw/types.h RMW_GID_STORAGE_SIZE (Jazzy).
GID_SIZE = 16
RCL_RET_OK = 0
RCL_RET_SUBSCRIPTION_TAKE_FAILED = 401
#: Messages taken per executor wake-up at most (~2-3 ms of takes); the bound keeps one
#: wake-up short whatever arrives meanwhile (a deeper history, topics.STATE_DEPTH, is
#: taken over several wake-ups, the executor waking at once while messages are queued).
MAX_TAKES_PER_WAKE = 128


class _Gid(ctypes.Structure):
    _fields_ = [("implementation_identifier", ctypes.c_char_p),
                ("data", ctypes.c_uint8 * GID_SIZE)]


class _MessageInfo(ctypes.Structure):
    _fields_ = [("source_timestamp", ctypes.c_int64),
                ("received_timestamp", ctypes.c_int64),
                ("publication_sequence_number", ctypes.c_uint64),
                ("reception_sequence_number", ctypes.c_uint64),
                ("publisher_gid", _Gid),
                ("from_intra_process", ctypes.c_bool)]


class _Allocator(ctypes.Structure):
    _fields_ = [("allocate", ctypes.c_void_p), ("deallocate", ctypes.c_void_p),
                ("reallocate", ctypes.c_void_p), ("zero_allocate", ctypes.c_void_p),
                ("state", ctypes.c_void_p)]


class _SerializedMessage(ctypes.Structure):     # rcutils_uint8_array_t
    _fields_ = [("buffer", ctypes.c_void_p), ("buffer_length", ctypes.c_size_t),
                ("buffer_capacity", ctypes.c_size_t), ("allocator", _Allocator)]


_libs: tuple | None = None


def _load() -> tuple:
    """(rcl_take_serialized_message, rcutils_uint8_array_init, rcutils_uint8_array_fini,
    rcutils_get_default_allocator)."""
    global _libs
    if _libs is None:
        rcl, rcutils = ctypes.CDLL("librcl.so"), ctypes.CDLL("librcutils.so")
        take = rcl.rcl_take_serialized_message
        take.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
        take.restype = ctypes.c_int
        init = rcutils.rcutils_uint8_array_init
        init.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p]
        init.restype = ctypes.c_int
        fini = rcutils.rcutils_uint8_array_fini
        fini.argtypes = [ctypes.c_void_p]
        fini.restype = ctypes.c_int
        allocator = rcutils.rcutils_get_default_allocator
        allocator.argtypes = []
        allocator.restype = _Allocator
        _libs = (take, init, fini, allocator)
    return _libs


def available() -> bool:
    """True if rcl's take can be called here (the libraries and symbols are found)."""
    try:
        _load()
    except (OSError, AttributeError):
        return False
    return True


class SenderAwareSubscription(Waitable):
    """``callback(data, gid)`` for each message on ``topic`` (``msg_type``), with the
    serialized bytes and the sender's 16-byte GID; ``callback(None, gid, length)`` for a
    message longer than ``max_bytes`` (not copied). Create with :func:`subscribe`."""

    def __init__(self, node: Node, msg_type, topic: str, callback: Callable, qos: QoSProfile,
                 max_bytes: int, callback_group: CallbackGroup | None = None):
        super().__init__(callback_group or node.default_callback_group)
        take, init, fini, allocator = _load()
        check_is_valid_msg_type(msg_type)   # imports its type support
        with node.handle:
            self.handle = _rclpy.Subscription(node.handle, msg_type, topic, qos.get_c_qos_profile())
        self.msg_type = msg_type
        self.callback = callback
        self.max_bytes = int(max_bytes)
        self._take = take
        self._fini = fini
        self._message = _SerializedMessage()
        self._allocator = allocator()
        if init(ctypes.byref(self._message), 256, ctypes.byref(self._allocator)) != RCL_RET_OK:
            raise MemoryError("cannot allocate a serialized message buffer")
        self._info = _MessageInfo()
        self._message_ref = ctypes.byref(self._message)
        self._info_ref = ctypes.byref(self._info)
        self._gid_address = ctypes.addressof(self._info) + _MessageInfo.publisher_gid.offset + \
            _Gid.data.offset
        self._identifier = get_rmw_implementation_identifier().encode()
        self._index: int | None = None
        #: True during a callback whose message has a newer one of the same sender behind it.
        self.newer_queued = False
        self._node = node
        self.destroyed = False

    # -- the subscription --------------------------------------------------------------
    @property
    def topic_name(self) -> str:
        with self.handle:
            return self.handle.get_topic_name()

    def get_publisher_count(self) -> int:
        with self.handle:
            return self.handle.get_publisher_count()

    def _take_one(self) -> tuple[bytes | None, bytes, int] | None:
        """The next queued message: (bytes or None if longer than max_bytes, GID, length)."""
        with self.handle:
            ret = self._take(self.handle.pointer, self._message_ref, self._info_ref, None)
        if ret != RCL_RET_OK:
            return None
        info, message = self._info, self._message
        if info.publisher_gid.implementation_identifier != self._identifier:
            raise RuntimeError("rmw_message_info_t layout differs from rmw/types.h (Jazzy): "
                               "the publisher GID cannot be read")
        gid = ctypes.string_at(self._gid_address, GID_SIZE)
        length = message.buffer_length
        data = None if length > self.max_bytes else ctypes.string_at(message.buffer, length)
        return data, gid, length

    def _dispatch(self, data: bytes | None, gid: bytes, length: int) -> None:
        if data is None:
            self.callback(None, gid, length)
        else:
            self.callback(data, gid)

    # -- Waitable ----------------------------------------------------------------------
    def is_ready(self, wait_set) -> bool:
        return self._index is not None and wait_set.is_ready("subscription", self._index)

    def take_data(self):
        """Take what is queued (at most MAX_TAKES_PER_WAKE), on the executor's thread, then
        hand each message to the callback in order: a flood from a second publisher costs
        one take each, not one executor wake-up each. During each callback
        :attr:`newer_queued` says whether a later message of the same sender was taken with
        it (a controller that fell behind answers only the newest state)."""
        batch = []
        for _ in range(MAX_TAKES_PER_WAKE):
            taken = self._take_one()
            if taken is None:
                break
            batch.append(taken)
        last = {gid: i for i, (_, gid, _) in enumerate(batch)}
        for i, taken in enumerate(batch):
            self.newer_queued = last[taken[1]] > i
            self._dispatch(*taken)
        self.newer_queued = False
        return None

    async def execute(self, taken_data) -> None:
        return None

    def get_num_entities(self) -> NumberOfEntities:
        return NumberOfEntities(num_subs=1)

    def add_to_wait_set(self, wait_set) -> None:
        with self.handle:
            self._index = wait_set.add_subscription(self.handle)

    def __enter__(self):
        self.handle.__enter__()

    def __exit__(self, t, v, tb):
        self.handle.__exit__(t, v, tb)

    def destroy(self) -> None:
        """Remove from the node and free the subscription and the buffer."""
        if self.destroyed:
            return
        self.destroyed = True
        self._node.remove_waitable(self)
        self.handle.destroy_when_not_in_use()
        self._fini(self._message_ref)


def subscribe(node: Node, msg_type, topic: str, callback: Callable, qos: QoSProfile,
              max_bytes: int) -> SenderAwareSubscription:
    """A :class:`SenderAwareSubscription` added to ``node`` (make it before spinning)."""
    sub = SenderAwareSubscription(node, msg_type, topic, callback, qos, max_bytes)
    node.add_waitable(sub)
    return sub


def subscribe_or_raw(node: Node, msg_type, topic: str, callback: Callable, qos: QoSProfile,
                     max_bytes: int, raw_qos: QoSProfile, consequence: str):
    """:func:`subscribe`, or where rcl's take is out of reach (:func:`available`) a plain raw
    subscription with ``raw_qos``, which cannot tell publishers apart: warned, with its
    ``consequence``."""
    if available():
        return subscribe(node, msg_type, topic, callback, qos, max_bytes)
    node.get_logger().warn(f"rcl's take is out of reach here: publishers on {topic} cannot be "
                           f"told apart ({consequence})")
    return node.create_subscription(msg_type, topic, callback, raw_qos, raw=True)
