"""Python mirrors of softarm's iceoryx2 contract (``contract/ipc/src/lib.rs``, crate ``softarm-ipc``).

Every payload a softarm process publishes is a ``#[repr(C)]`` Rust struct with a
``#[type_name("softarm::...")]`` attribute. iceoryx2 connects two ports only when the payload's
type name, size and alignment agree, so each mirror here is a ``ctypes.Structure`` with the same
fields in the same order and a ``type_name()`` classmethod returning the Rust ``#[type_name]``
string: the iceoryx2 Python package (0.10) calls it when a service is opened.

Service names are ``<namespace>/<service>`` (namespace default ``softarm/<robot-id>``, e.g.
``softarm/sim/setpoint``); every service is opened with the settings softarm's Rust side uses
(``SERVICES``), so a Python process may open a service first (``open_or_create``) without
locking the stack out, or join a running stack.

Typical use::

    import softarm_ipc as sa

    node = sa.open_node("softarm/sim")
    setpoints = sa.subscribe(node, "softarm/sim", "setpoint")
    for sp in setpoints.receive_all():
        print(sp.seq, list(sp.actuation), sa.ControllerState.name_of(sp.state))

Units: positions in metres (tracker/base frame), actuation normalised per actuator to [0, 1],
stamps CLOCK_MONOTONIC in ns. ``tests/python.rs`` checks every mirror's size, alignment, field
offsets and field types and the service settings against the Rust side.

Requires ``pip install iceoryx2==0.10.0`` (the ctypes mirrors alone need nothing beyond the
standard library: ``import softarm_ipc`` works without iceoryx2, for layout checks).
"""

from __future__ import annotations

import ctypes
import enum
import re
import time
from dataclasses import dataclass
from typing import Any, Iterator, Optional, Type

try:  # The mirrors are usable (and their layout checkable) without iceoryx2.
    import iceoryx2 as iox2
except ImportError:  # pragma: no cover - depends on the machine
    iox2 = None

# --- constants (contract/ipc/src/lib.rs, contract/space/src/lib.rs) --------------------------------

MAX_ACTUATORS = 16
"""Most actuators an arm may have: the capacity of an ``Actuators``."""
MAX_WAYPOINTS = 16
"""Most conditioning points / way-points in one set."""
MAX_REASON = 200
"""Longest reason text in a ``WaypointReply``."""
MAX_NODES = 16
"""Nodes that may share one service: the processes of a stack and a few clients."""
MAX_SUBSCRIBERS = 8
"""Subscribers (or clients) per service."""
STATS_HISTORY = 64
"""Executions whose stats reach a late subscriber."""
NO_DEMO = 0xFFFF_FFFF
"""``Setpoint.demo`` / ``demo_class`` when not demonstrating (u32::MAX)."""

Position = ctypes.c_double * 3
"""``[f64; 3]``: a position in metres."""


class ControllerState(enum.IntEnum):
    """What the controller is doing (``Setpoint.state``, ``ControllerStatus.state``)."""

    IDLE = 0
    """No way-point set: holds the last setpoint."""
    DEMONSTRATE = 1
    """Playing demonstration sequences (training)."""
    # 2 was PLAN, never set; left free.
    EXECUTE = 3
    """Executing a way-point set."""
    HOLD = 4
    """Tracker or motor data too old: setpoint frozen at the last safe value."""
    STOPPED = 5
    """E-stop latched."""

    @classmethod
    def name_of(cls, value: int) -> str:
        """The state's name as ``softarm status`` prints it, ``"?"`` for an unknown value."""
        try:
            return cls(value).name
        except ValueError:
            return "?"


class DriverState(enum.IntEnum):
    """What a driver does with the setpoints it receives (``MotorState.state``)."""

    FOLLOWING = 0
    """Applying each setpoint."""
    HOLDING = 1
    """No setpoint for a while: the last position is held."""
    OFF = 2
    """Torque off: before the first setpoint, or when setpoints stopped for too long."""
    STOPPED = 3
    """The e-stop is latched: setpoints are ignored until a reset."""
    FAULT = 4
    """A motor reported a hardware error: it gets no more commands, the others hold."""
    DEGRADED = 5
    """Applying each setpoint while the bus loses replies (``loss_permille``) or the motor
    data is older than the controller's input time-out."""

    @classmethod
    def name_of(cls, value: int) -> str:
        """The state's name, ``"?"`` for an unknown value."""
        try:
            return cls(value).name
        except ValueError:
            return "?"


# --- payloads -----------------------------------------------------------------------------------


def _plain(value: Any) -> Any:
    """A ctypes value as plain Python (lists for arrays, dicts for structs, an
    ``Actuators`` as the arm's values)."""
    if isinstance(value, Actuators):
        return value.to_list()
    if isinstance(value, ctypes.Array):
        return [_plain(v) for v in value]
    if isinstance(value, _Payload):
        return value.to_dict()
    return value


class _Payload(ctypes.Structure):
    """Base of the mirrors: the iceoryx2 type name and conversions."""

    TYPE_NAME = ""
    """The Rust ``#[type_name(...)]`` string."""

    @classmethod
    def type_name(cls) -> str:
        """The type name iceoryx2 matches across processes and languages."""
        return cls.TYPE_NAME

    def to_dict(self) -> dict[str, Any]:
        """The fields as plain Python values (arrays as lists)."""
        return {name: _plain(getattr(self, name)) for name, *_ in self._fields_}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.to_dict()})"


class Actuators(_Payload):
    """``Actuators``: one value per actuator of the arm, in the arm's order (room for
    ``MAX_ACTUATORS``; ``count`` of them are the arm's, the rest zero)."""

    TYPE_NAME = "softarm::Actuators"
    _fields_ = [
        ("count", ctypes.c_uint32),
        ("_pad", ctypes.c_uint32),
        ("values", ctypes.c_double * MAX_ACTUATORS),
    ]

    @classmethod
    def of(cls, values: "list[float]") -> "Actuators":
        """The arm's values, at most ``MAX_ACTUATORS``."""
        if len(values) > MAX_ACTUATORS:
            raise ValueError(f"{len(values)} actuators; at most {MAX_ACTUATORS}")
        a = cls()
        a.count = len(values)
        for i, v in enumerate(values):
            a.values[i] = v
        return a

    def to_list(self) -> "list[float]":
        """The arm's values (``count`` of them)."""
        return list(self.values[: min(self.count, MAX_ACTUATORS)])

    def __len__(self) -> int:
        return min(self.count, MAX_ACTUATORS)

    def __getitem__(self, i: int) -> float:
        return self.to_list()[i]

    def __iter__(self):
        return iter(self.to_list())


class Setpoint(_Payload):
    """``setpoint``: one per controller tick, the actuation to apply."""

    TYPE_NAME = "softarm::Setpoint.v2"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("actuation", Actuators),
        ("state", ctypes.c_uint32),  # ControllerState
        ("demo", ctypes.c_uint32),  # while demonstrating: its index, else NO_DEMO
        ("demo_class", ctypes.c_uint32),  # its class, else NO_DEMO
        ("execution", ctypes.c_uint32),
    ]


class TrackerSample(_Payload):
    """``tracker``: an end-effector position from the tracker (or the simulated plant)."""

    TYPE_NAME = "softarm::TrackerSample"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("position", Position),
    ]


class MotorState(_Payload):
    """``motor_state``: what the actuators reached and what the driver says about them."""

    TYPE_NAME = "softarm::MotorState.v5"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("actuation", Actuators),
        ("current_a", Actuators),  # motor currents (A); NaN where not measured (the sim)
        ("faults", ctypes.c_uint64),  # replies lost (dropped + crc_errors) plus reopens
        ("dropped", ctypes.c_uint64),  # replies asked for that never came whole
        ("crc_errors", ctypes.c_uint64),  # replies with a wrong checksum
        ("garbage_bytes", ctypes.c_uint64),  # bytes that belonged to no packet
        ("timeouts", ctypes.c_uint64),  # reads that ended with a reply missing
        ("reopens", ctypes.c_uint64),  # port reopened (I/O error, device gone)
        ("setpoint_cycles", ctypes.c_uint64),  # cycles with a fresh setpoint to follow
        ("goal_writes", ctypes.c_uint64),  # goal writes sent
        ("state", ctypes.c_uint32),  # DriverState
        ("loss_permille", ctypes.c_uint32),  # replies lost per 1000 over the last second
        # Dynamixel error bits per motor, as many as ``actuation`` has
        ("hardware_error", ctypes.c_uint8 * MAX_ACTUATORS),
        ("age_cycles", ctypes.c_uint16),  # driver cycles since the oldest data was asked for
    ]


class ConditioningSample(_Payload):
    """``cp_sample``: controller -> learner at each conditioning point."""

    TYPE_NAME = "softarm::ConditioningSample.v5"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("set_id", ctypes.c_uint64),
        ("execution", ctypes.c_uint32),
        ("point", ctypes.c_uint32),
        ("points", ctypes.c_uint32),
        ("_pad", ctypes.c_uint32),
        ("actuation", Actuators),
        ("desired", Position),
        ("reached", Position),
        ("next_point", ctypes.c_uint32),
        ("next_execution", ctypes.c_uint32),
        ("next_desired", Position),
        ("measured", Actuators),  # NaN without motor state
        ("conditioned", Actuators),  # the estimate the point's group ran on
    ]


class EstimateRequest(_Payload):
    """``estimate_request``: controller -> learner, the first estimates of a new set."""

    TYPE_NAME = "softarm::EstimateRequest"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("set_id", ctypes.c_uint64),
        ("count", ctypes.c_uint32),
        ("_pad", ctypes.c_uint32),
        ("desired", Position * MAX_WAYPOINTS),
    ]


class ActuationEstimate(_Payload):
    """``estimate``: the learner's actuation for a conditioning point."""

    TYPE_NAME = "softarm::ActuationEstimate.v4"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("set_id", ctypes.c_uint64),
        ("point", ctypes.c_uint32),
        ("execution", ctypes.c_uint32),  # the one it is for (1-based)
        ("actuation", Actuators),
        ("within", ctypes.c_uint32),  # 1: corrected within its execution
        ("beyond_reach", ctypes.c_uint32),  # 1: its target is beyond the arm's reach
        ("answers_ns", ctypes.c_uint64),  # the stamp of the sample it answers, 0 if none
    ]


class WaypointSet(_Payload):
    """Request of ``waypoints``: a way-point set to execute."""

    TYPE_NAME = "softarm::WaypointSet"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("duration_s", ctypes.c_double),
        ("executions", ctypes.c_uint32),
        ("count", ctypes.c_uint32),
        ("times_s", ctypes.c_double * MAX_WAYPOINTS),
        ("positions_m", Position * MAX_WAYPOINTS),
    ]


class WaypointReply(_Payload):
    """Response of ``waypoints``: the set's id when accepted, else the reason."""

    TYPE_NAME = "softarm::WaypointReply"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("set_id", ctypes.c_uint64),  # 0 when rejected
        ("accepted", ctypes.c_uint32),
        ("reason_len", ctypes.c_uint32),
        ("reason", ctypes.c_uint8 * MAX_REASON),
    ]

    def reason_text(self) -> str:
        """The rejection's reason."""
        n = min(self.reason_len, MAX_REASON)
        return bytes(self.reason[:n]).decode("utf-8", errors="replace")


class DemonstrateRequest(_Payload):
    """Request of ``demonstrate``: play the demonstration sequences."""

    TYPE_NAME = "softarm::DemonstrateRequest"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("seed", ctypes.c_uint64),
    ]


class DemonstrateReply(_Payload):
    """Response of ``demonstrate``."""

    TYPE_NAME = "softarm::DemonstrateReply"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("accepted", ctypes.c_uint32),
        ("demos", ctypes.c_uint32),  # demonstrations that will be played
        ("duration_s", ctypes.c_double),  # how long they take in all
    ]


class ExecutionStats(_Payload):
    """``stats``: one per finished execution (errors at the conditioning points, Eq. 9)."""

    TYPE_NAME = "softarm::ExecutionStats.v3"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("set_id", ctypes.c_uint64),
        ("execution", ctypes.c_uint32),  # 1-based within the set
        ("executions", ctypes.c_uint32),
        ("count", ctypes.c_uint32),
        ("reconditions", ctypes.c_uint32),  # learner estimates applied during it
        ("within", ctypes.c_uint32),  # bit n: point n ran corrected within the execution
        ("beyond_reach", ctypes.c_uint32),  # bit n: point n's target is beyond reach
        ("errors_m", ctypes.c_double * MAX_WAYPOINTS),
        ("mean_m", ctypes.c_double),
        ("max_m", ctypes.c_double),
    ]

    def errors(self) -> list[float]:
        """The errors (m) of the set's points (``count`` of them)."""
        return list(self.errors_m[: min(self.count, MAX_WAYPOINTS)])


class Latency(_Payload):
    """Min / p50 / p99 / p99.9 / max of the tick wake-up latency (ns)."""

    TYPE_NAME = "softarm::Latency"
    _fields_ = [
        ("min_ns", ctypes.c_uint64),
        ("p50_ns", ctypes.c_uint64),
        ("p99_ns", ctypes.c_uint64),
        ("p999_ns", ctypes.c_uint64),
        ("max_ns", ctypes.c_uint64),
        ("samples", ctypes.c_uint64),
    ]


class ControllerStatus(_Payload):
    """``status``: the controller's state, ~10 Hz."""

    TYPE_NAME = "softarm::ControllerStatus.v4"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("state", ctypes.c_uint32),  # ControllerState
        ("execution", ctypes.c_uint32),
        ("set_id", ctypes.c_uint64),
        ("rate_hz", ctypes.c_double),
        ("ticks", ctypes.c_uint64),
        ("overruns", ctypes.c_uint64),
        ("latency", Latency),
        ("tracker_age_ns", ctypes.c_uint64),  # u64::MAX if none yet
        ("motor_age_ns", ctypes.c_uint64),
        ("model_loaded", ctypes.c_uint32),
        ("reconditions_current", ctypes.c_uint32),
        ("reconditions_last", ctypes.c_uint32),
        ("outbox_backlog", ctypes.c_uint32),
        ("outbox_dropped", ctypes.c_uint64),
        ("samples_dropped", ctypes.c_uint64),
        ("held_solves", ctypes.c_uint64),
        ("lag_ns", ctypes.c_uint64),  # u64::MAX until measured
        ("lead_ns", ctypes.c_uint64),
        ("points_unseen", ctypes.c_uint64),  # points the tracker did not see at their time
    ]


class EstopState(_Payload):
    """``estop``: the latched e-stop state."""

    TYPE_NAME = "softarm::EstopState"
    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("engaged", ctypes.c_uint32),  # 1 engaged, 0 released (an explicit reset)
        ("_pad", ctypes.c_uint32),
    ]


PAYLOADS: list[Type[_Payload]] = [
    Actuators,
    Setpoint,
    TrackerSample,
    MotorState,
    ConditioningSample,
    EstimateRequest,
    ActuationEstimate,
    WaypointSet,
    WaypointReply,
    DemonstrateRequest,
    DemonstrateReply,
    ExecutionStats,
    Latency,
    ControllerStatus,
    EstopState,
]
"""Every mirror, in the order of ``contract/ipc/src/lib.rs``."""

# --- services -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class PubSubSettings:
    """A publish-subscribe service's payload and settings, as ``Node::pubsub`` opens it."""

    payload: Type[_Payload]
    history: int
    buffer: int
    publishers: int
    subscribers: int = MAX_SUBSCRIBERS
    nodes: int = MAX_NODES

    @property
    def subscriber_max_buffer_size(self) -> int:
        """What the Rust side sets: ``buffer.max(history).max(1)``."""
        return max(self.buffer, self.history, 1)


@dataclass(frozen=True)
class ReqResSettings:
    """A request-response service's types and settings, as ``Node::reqres`` opens it."""

    request: Type[_Payload]
    response: Type[_Payload]
    clients: int = MAX_SUBSCRIBERS
    servers: int = 1
    nodes: int = MAX_NODES
    active_requests_per_client: int = 2
    response_buffer: int = 2


SERVICES: dict[str, PubSubSettings] = {
    "setpoint": PubSubSettings(Setpoint, history=1, buffer=4, publishers=2),
    "tracker": PubSubSettings(TrackerSample, history=1, buffer=64, publishers=2),
    "motor_state": PubSubSettings(MotorState, history=1, buffer=64, publishers=2),
    "cp_sample": PubSubSettings(ConditioningSample, history=0, buffer=64, publishers=2),
    "estimate_request": PubSubSettings(EstimateRequest, history=0, buffer=8, publishers=2),
    "estimate": PubSubSettings(ActuationEstimate, history=0, buffer=64, publishers=2),
    "stats": PubSubSettings(
        ExecutionStats, history=STATS_HISTORY, buffer=STATS_HISTORY, publishers=2
    ),
    "status": PubSubSettings(ControllerStatus, history=1, buffer=4, publishers=2),
    "estop": PubSubSettings(EstopState, history=1, buffer=4, publishers=4),
}
"""The publish-subscribe services of a stack, by the name after the namespace."""

REQUEST_RESPONSE: dict[str, ReqResSettings] = {
    "waypoints": ReqResSettings(WaypointSet, WaypointReply),
    "demonstrate": ReqResSettings(DemonstrateRequest, DemonstrateReply),
}
"""The request-response services of a stack."""

_NAMESPACE = re.compile(r"[A-Za-z0-9_./-]{1,100}")


def check_namespace(namespace: str) -> str:
    """The namespace if softarm accepts it (``Namespace::new``), else ``ValueError``."""
    if (
        not _NAMESPACE.fullmatch(namespace)
        or namespace.startswith("/")
        or namespace.endswith("/")
    ):
        raise ValueError(
            f"namespace {namespace!r} is not valid: use 1 to 100 of A-Z a-z 0-9 _ - . /, "
            "not starting or ending with /"
        )
    return namespace


def service_name(namespace: str, service: str) -> str:
    """``<namespace>/<service>``, e.g. ``softarm/sim/setpoint``."""
    return f"{check_namespace(namespace)}/{service}"


def node_name(namespace: str, role: str) -> str:
    """``<namespace>/<role>``, the tail kept when longer than 100 (as the Rust side does)."""
    full = f"{check_namespace(namespace)}/{role}"
    return full[-100:] if len(full) > 100 else full


def _need_iceoryx2() -> Any:
    if iox2 is None:
        raise RuntimeError(
            "the iceoryx2 Python package is missing: pip install iceoryx2==0.10.0"
        )
    return iox2


def open_node(namespace: str, role: str = "python") -> Any:
    """An iceoryx2 node named ``<namespace>/<role>`` on iceoryx2's default config, as softarm's
    processes make theirs: ``softarm status`` lists it under ``role`` (the part before a ``.``).

    Nodes of processes that died are cleaned up. Signals stay with Python (Ctrl-C raises
    ``KeyboardInterrupt``); iceoryx2's log level is set to errors only.
    """
    iox = _need_iceoryx2()
    iox.set_log_level(iox.LogLevel.Error)
    node = (
        iox.NodeBuilder.new()
        .name(iox.NodeName.new(node_name(namespace, role)))
        .signal_handling_mode(iox.SignalHandlingMode.Disabled)
        .create(iox.ServiceType.Ipc)
    )
    try:
        node.try_cleanup_dead_nodes()
    except Exception:  # best effort, as on the Rust side
        pass
    return node


def open_service(node: Any, namespace: str, service: str) -> Any:
    """Opens (or creates) publish-subscribe service ``service`` of a stack with softarm's
    settings; returns the iceoryx2 port factory."""
    s = SERVICES[service]
    iox = _need_iceoryx2()
    return (
        node.service_builder(iox.ServiceName.new(service_name(namespace, service)))
        .publish_subscribe(s.payload)
        .history_size(s.history)
        .subscriber_max_buffer_size(s.subscriber_max_buffer_size)
        .max_publishers(s.publishers)
        .max_subscribers(s.subscribers)
        .max_nodes(s.nodes)
        .open_or_create()
    )


def open_request_response(node: Any, namespace: str, service: str) -> Any:
    """Opens (or creates) request-response service ``service`` (``waypoints``,
    ``demonstrate``) with softarm's settings; returns the iceoryx2 port factory."""
    s = REQUEST_RESPONSE[service]
    iox = _need_iceoryx2()
    return (
        node.service_builder(iox.ServiceName.new(service_name(namespace, service)))
        .request_response(s.request, s.response)
        .max_clients(s.clients)
        .max_servers(s.servers)
        .max_nodes(s.nodes)
        .max_active_requests_per_client(s.active_requests_per_client)
        .max_response_buffer_size(s.response_buffer)
        .open_or_create()
    )


class Subscription:
    """A subscriber to one softarm service; samples come out as copies of the payload."""

    def __init__(self, node: Any, namespace: str, service: str) -> None:
        self.name = service_name(namespace, service)
        self.payload_type = SERVICES[service].payload
        self.service = open_service(node, namespace, service)
        self.subscriber = self.service.subscriber_builder().create()

    def receive(self) -> Optional[_Payload]:
        """The next payload (a copy; the shared-memory sample is released), or ``None``."""
        sample = self.subscriber.receive()
        if sample is None:
            return None
        try:
            return self.payload_type.from_buffer_copy(sample.payload().contents)
        finally:
            sample.delete()

    def receive_all(self) -> Iterator[_Payload]:
        """Every payload waiting now."""
        while True:
            p = self.receive()
            if p is None:
                return
            yield p


def subscribe(node: Any, namespace: str, service: str) -> Subscription:
    """A subscription to ``<namespace>/<service>``, e.g. ``subscribe(node, ns, "setpoint")``.
    Late subscribers get the service's history: the newest setpoint/status/estop, the last 64
    stats."""
    return Subscription(node, namespace, service)


def publisher(node: Any, namespace: str, service: str) -> Any:
    """A publisher on ``<namespace>/<service>`` (most services allow 2 publishers: the stack's
    process and one more). Send with ``pub.send_copy(payload)``."""
    return open_service(node, namespace, service).publisher_builder().create()


def now_ns() -> int:
    """CLOCK_MONOTONIC in ns, the clock of every ``stamp_ns``."""
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


def submit(
    node: Any,
    namespace: str,
    times_s: list[float],
    positions_m: list[list[float]],
    duration_s: float,
    executions: int = 1,
    timeout_s: float = 5.0,
) -> WaypointReply:
    """Sends a way-point set to the controller (``waypoints``) and waits for its reply, as
    ``softarm submit`` does; the controller validates it (``reply.accepted``,
    ``reply.reason_text()``). ``TimeoutError`` when no controller answers."""
    if len(times_s) != len(positions_m) or not 0 < len(times_s) <= MAX_WAYPOINTS:
        raise ValueError(f"1 to {MAX_WAYPOINTS} points, each with a time and a position")
    request = WaypointSet(
        seq=now_ns(),
        stamp_ns=now_ns(),
        duration_s=duration_s,
        executions=executions,
        count=len(times_s),
    )
    for i, (t, p) in enumerate(zip(times_s, positions_m)):
        request.times_s[i] = t
        request.positions_m[i] = Position(*p)
    client = open_request_response(node, namespace, "waypoints").client_builder().create()
    pending = client.send_copy(request)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        response = pending.receive()
        if response is not None:
            try:
                return WaypointReply.from_buffer_copy(response.payload().contents)
            finally:
                response.delete()
        time.sleep(0.01)
    raise TimeoutError(f"no reply on {service_name(namespace, 'waypoints')} in {timeout_s} s")


def layout(t: Type[ctypes.Structure]) -> dict[str, Any]:
    """A mirror's layout: size, alignment, field offsets and field types in Rust notation
    (``u64``, ``[f64; 6]``, ``Latency``), and its iceoryx2 type name."""
    return {
        "size": ctypes.sizeof(t),
        "align": ctypes.alignment(t),
        "fields": {name: getattr(t, name).offset for name, *_ in t._fields_},
        "types": {name: rust_type(ft) for name, ft, *_ in t._fields_},
        "type_name": t.type_name() if hasattr(t, "type_name") else t.__name__,
    }


_SCALARS = {
    ctypes.c_uint8: "u8",
    ctypes.c_uint16: "u16",
    ctypes.c_uint32: "u32",
    ctypes.c_uint64: "u64",
    ctypes.c_int8: "i8",
    ctypes.c_int16: "i16",
    ctypes.c_int32: "i32",
    ctypes.c_int64: "i64",
    ctypes.c_float: "f32",
    ctypes.c_double: "f64",
}


def rust_type(t: Any) -> str:
    """A ctypes type in the notation of Rust's ``std::any::type_name`` (paths stripped)."""
    if isinstance(t, type) and issubclass(t, ctypes.Array):
        return f"[{rust_type(t._type_)}; {t._length_}]"
    for c, name in _SCALARS.items():
        if t is c:
            return name
    return t.__name__


__all__ = [
    "MAX_ACTUATORS",
    "MAX_WAYPOINTS",
    "MAX_REASON",
    "MAX_NODES",
    "MAX_SUBSCRIBERS",
    "STATS_HISTORY",
    "NO_DEMO",
    "Actuators",
    "Position",
    "ControllerState",
    "DriverState",
    "PAYLOADS",
    "SERVICES",
    "REQUEST_RESPONSE",
    "PubSubSettings",
    "ReqResSettings",
    "check_namespace",
    "service_name",
    "node_name",
    "open_node",
    "open_service",
    "open_request_response",
    "Subscription",
    "subscribe",
    "publisher",
    "submit",
    "now_ns",
    "layout",
    "rust_type",
] + [t.__name__ for t in PAYLOADS]
