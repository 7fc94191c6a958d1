"""A stand-in for ROS 2's Python client library, for tests on machines without ROS 2.

:func:`install` puts the modules ``rclpy``, ``rclpy.node``, ``rclpy.qos``, ``rclpy.qos_overriding_options``,
``rclpy.parameter``, ``rclpy.exceptions``, ``rclpy.executors``, ``rclpy.utilities``, ``rcl_interfaces`` and
``rcl_interfaces.msg``, and the message packages of the project's typestore (``std_msgs.msg``, ``sensor_msgs.msg``,
``vision_msgs.msg``, ``hbni_msgs.msg``, ...), into ``sys.modules``. They keep rclpy's signatures (Humble to Jazzy)
and the behaviour a node relies on:

- ``--ros-args`` as rcl parses them: ``-r``/``--remap FROM:=TO`` (``__ns``, ``__node`` included), ``-p``/``--param
  NAME:=VALUE`` (values read as YAML), ``--params-file`` (``/**`` or the node's name), until ``--`` or the end;
  ``rclpy.utilities.remove_ros_args`` drops them;
- a node's name and namespace from those remaps; topic names expanded (``~``, relative, absolute) and remapped;
- ``declare_parameter(name, value, descriptor, ignore_override)``: an override replaces the value, a value of another
  type than the descriptor's is an ``InvalidParameterTypeException``, one outside the descriptor's range an
  ``InvalidParameterValueException``, a second declaration a ``ParameterAlreadyDeclaredException``; the node itself
  declares ``use_sim_time``, and its clock then reads the simulation's time (:meth:`World.set_time`);
- QoS profiles with their policies, ``qos_profile_sensor_data``, and ``QoSOverridingOptions`` declaring the
  read-only ``qos_overrides.<topic>.<publisher|subscription>.<policy>`` parameters that override them;
- ``spin`` plays :attr:`World.script` (topic, message, simulation time) to the matching subscriptions, then stops
  as Ctrl-C does; ``try_shutdown`` from another thread ends it as an external shutdown.

Everything a node does is recorded on :data:`WORLD` (``inits``, ``nodes``; per node its parameters, descriptors,
subscriptions, publishers with their messages, and log).
"""

from __future__ import annotations

import enum
import sys
import threading
import time
import types
from dataclasses import dataclass, field
from typing import Any

import yaml


class RCLError(RuntimeError):
    """rcl's error for malformed ROS arguments."""


def parse_ros_args(args: list[str]) -> tuple[list[str], dict[str, str], dict[str, Any]]:
    """``(other arguments, remaps, parameter overrides)`` of a command line, as rcl reads it."""
    rest, remaps, params = [], {}, {}
    i, inside = 0, False
    while i < len(args):
        arg = args[i]
        if arg == "--ros-args":
            inside = True
        elif inside and arg == "--":
            inside = False
        elif not inside:
            rest.append(arg)
        elif arg in ("-r", "--remap", "-p", "--param", "--params-file", "--log-level", "-e", "--enclave"):
            if i + 1 >= len(args):
                raise RCLError(f"Couldn't parse trailing {arg} flag. No argument provided")
            value = args[i + 1]
            if arg in ("-r", "--remap", "-p", "--param"):
                name, sep, target = value.partition(":=")
                if not sep or not name:
                    raise RCLError(f"Couldn't parse {arg} argument {value!r}")
                if arg in ("-r", "--remap"):
                    remaps[name] = target
                else:
                    params[name] = yaml.safe_load(target)
            elif arg == "--params-file":
                with open(value) as fh:
                    for node, content in (yaml.safe_load(fh) or {}).items():
                        params.update({(node, k): v for k, v in content.get("ros__parameters", {}).items()})
            i += 1
        else:
            raise RCLError(f"Couldn't parse ROS argument {arg!r}")
        i += 1
    return rest, remaps, params


# rcl_interfaces.msg


class ParameterType:
    PARAMETER_NOT_SET = 0
    PARAMETER_BOOL = 1
    PARAMETER_INTEGER = 2
    PARAMETER_DOUBLE = 3
    PARAMETER_STRING = 4
    PARAMETER_BYTE_ARRAY = 5
    PARAMETER_BOOL_ARRAY = 6
    PARAMETER_INTEGER_ARRAY = 7
    PARAMETER_DOUBLE_ARRAY = 8
    PARAMETER_STRING_ARRAY = 9


class _Message:
    """A generated message class: keyword fields with defaults; an unknown keyword is refused."""

    _fields: dict[str, Any] = {}

    def __init__(self, **kwargs: Any) -> None:
        unknown = set(kwargs) - set(self._fields)
        assert not unknown, f"Invalid arguments passed to constructor: {', '.join(sorted(unknown))}"
        for name, default in self._fields.items():
            setattr(self, name, kwargs.get(name, list(default) if isinstance(default, list) else default))


class FloatingPointRange(_Message):
    _fields = {"from_value": 0.0, "to_value": 0.0, "step": 0.0}


class IntegerRange(_Message):
    _fields = {"from_value": 0, "to_value": 0, "step": 0}


class ParameterDescriptor(_Message):
    _fields = {
        "name": "",
        "type": 0,
        "description": "",
        "additional_constraints": "",
        "read_only": False,
        "dynamic_typing": False,
        "floating_point_range": [],
        "integer_range": [],
    }


# rclpy.exceptions


class ParameterAlreadyDeclaredException(Exception):
    pass


class InvalidParameterTypeException(Exception):
    def __init__(self, parameter: Any, expected_type: Any) -> None:
        super().__init__(
            f"Trying to set parameter '{parameter.name}' to '{parameter.value}' of type '{parameter.type_.name}', "
            f"expecting type '{expected_type}'"
        )


class InvalidParameterValueException(Exception):
    def __init__(self, parameter: str, value: Any, reason: str) -> None:
        super().__init__(f"Invalid parameter value ({value}) for parameter. Reason: {reason}")
        self.parameter, self.value, self.reason = parameter, value, reason


class ExternalShutdownException(Exception):
    pass


# rclpy.parameter


class Parameter:
    class Type(enum.IntEnum):
        NOT_SET = 0
        BOOL = 1
        INTEGER = 2
        DOUBLE = 3
        STRING = 4
        BYTE_ARRAY = 5
        BOOL_ARRAY = 6
        INTEGER_ARRAY = 7
        DOUBLE_ARRAY = 8
        STRING_ARRAY = 9

        @classmethod
        def from_parameter_value(cls, value: Any) -> Parameter.Type:
            if value is None:
                return cls.NOT_SET
            if isinstance(value, bool):
                return cls.BOOL
            if isinstance(value, int):
                return cls.INTEGER
            if isinstance(value, float):
                return cls.DOUBLE
            if isinstance(value, str):
                return cls.STRING
            if isinstance(value, (list, tuple)):
                for kind, array in ((bytes, cls.BYTE_ARRAY), (bool, cls.BOOL_ARRAY), (int, cls.INTEGER_ARRAY)):
                    if all(isinstance(v, kind) for v in value):
                        return array
                if all(isinstance(v, float) for v in value):
                    return cls.DOUBLE_ARRAY
                if all(isinstance(v, str) for v in value):
                    return cls.STRING_ARRAY
            raise TypeError(f"The given value is not one of the allowed types '{value}'.")

    def __init__(self, name: str, type_: Parameter.Type | None = None, value: Any = None) -> None:
        self.name, self.value = name, value
        self.type_ = Parameter.Type.from_parameter_value(value) if type_ is None else type_


# rclpy.qos


class HistoryPolicy(enum.IntEnum):
    SYSTEM_DEFAULT = 0
    KEEP_LAST = 1
    KEEP_ALL = 2
    UNKNOWN = 3


class ReliabilityPolicy(enum.IntEnum):
    SYSTEM_DEFAULT = 0
    RELIABLE = 1
    BEST_EFFORT = 2
    UNKNOWN = 3


class DurabilityPolicy(enum.IntEnum):
    SYSTEM_DEFAULT = 0
    TRANSIENT_LOCAL = 1
    VOLATILE = 2
    UNKNOWN = 3


class QoSPolicyKind(enum.IntEnum):
    DURABILITY = 1 << 1
    HISTORY = 1 << 4
    RELIABILITY = 1 << 6
    DEPTH = 1 << 7


@dataclass
class QoSProfile:
    """rclpy's QoSProfile: ``history`` (keep last when only ``depth`` is given), ``depth``, ``reliability``,
    ``durability``."""

    history: HistoryPolicy = HistoryPolicy.KEEP_LAST
    depth: int = 0
    reliability: ReliabilityPolicy = ReliabilityPolicy.RELIABLE
    durability: DurabilityPolicy = DurabilityPolicy.VOLATILE

    def __post_init__(self) -> None:
        if self.history == HistoryPolicy.KEEP_LAST and self.depth < 1:
            raise ValueError("A QoSProfile with history KEEP_LAST needs a depth")


qos_profile_sensor_data = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=5,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)


class QoSOverridingOptions:
    def __init__(self, policy_kinds: Any, *, callback: Any = None, entity_id: str | None = None) -> None:
        self.policy_kinds, self.callback, self.entity_id = tuple(policy_kinds), callback, entity_id

    @classmethod
    def with_default_policies(cls, *, callback: Any = None, entity_id: str | None = None) -> QoSOverridingOptions:
        return cls(
            (QoSPolicyKind.HISTORY, QoSPolicyKind.DEPTH, QoSPolicyKind.RELIABILITY),
            callback=callback,
            entity_id=entity_id,
        )


_POLICY_ENUMS = {"history": HistoryPolicy, "reliability": ReliabilityPolicy, "durability": DurabilityPolicy}


# rclpy.node


@dataclass
class Time:
    nanoseconds: int
    clock_type: str


class Clock:
    """The node's clock: ROS time, the simulation's while ``use_sim_time`` is true, else the system's."""

    def __init__(self, node: Node) -> None:
        self._node = node

    def now(self) -> Time:
        if self._node.get_parameter("use_sim_time").value:
            return Time(WORLD.sim_time, "ROS_TIME")
        return Time(time.time_ns(), "ROS_TIME")


@dataclass
class Logger:
    records: list[tuple[str, str]] = field(default_factory=list)

    def _log(self, level: str, message: str) -> bool:
        self.records.append((level, message))
        return True

    def debug(self, message: str, **kwargs: Any) -> bool:
        return self._log("debug", message)

    def info(self, message: str, **kwargs: Any) -> bool:
        return self._log("info", message)

    def warning(self, message: str, **kwargs: Any) -> bool:
        return self._log("warning", message)

    warn = warning

    def error(self, message: str, **kwargs: Any) -> bool:
        return self._log("error", message)


@dataclass
class Subscription:
    msg_type: type
    topic_name: str
    callback: Any
    qos_profile: QoSProfile


@dataclass
class Publisher:
    msg_type: type
    topic_name: str
    qos_profile: QoSProfile
    messages: list = field(default_factory=list)

    def publish(self, msg: Any) -> None:
        if not isinstance(msg, self.msg_type):
            raise TypeError(f"Expected {self.msg_type.__name__}, got {type(msg).__name__}")
        self.messages.append(msg)


class Node:
    def __init__(
        self,
        node_name: str,
        *,
        context: Any = None,
        cli_args: list[str] | None = None,
        namespace: str | None = None,
        use_global_arguments: bool = True,
        enable_rosout: bool = True,
        start_parameter_services: bool = True,
        parameter_overrides: list[Parameter] | None = None,
        allow_undeclared_parameters: bool = False,
        automatically_declare_parameters_from_overrides: bool = False,
    ) -> None:
        if not WORLD.initialized:
            raise RuntimeError("rclpy.init() has not been called")
        remaps = dict(WORLD.remaps) if use_global_arguments else {}
        self._name = remaps.pop("__node", remaps.pop("__name", node_name))
        ns = remaps.pop("__ns", namespace or "/")
        self._namespace = ns if ns.startswith("/") else f"/{ns}"
        self._remaps = remaps
        self._overrides = {}
        for key, value in (WORLD.params if use_global_arguments else {}).items():
            if isinstance(key, tuple):  # from a params file: /** or this node
                target, key = key
                if target not in ("/**", self._name, self.get_fully_qualified_name()):
                    continue
            self._overrides[key] = value
        self.parameters: dict[str, Parameter] = {}
        self.descriptors: dict[str, ParameterDescriptor] = {}
        self.subscriptions: list[Subscription] = []
        self.publishers: list[Publisher] = []
        self.logger = Logger()
        self.destroyed = False
        self._clock = Clock(self)
        self.declare_parameter("use_sim_time", False)  # as rclpy's TimeSource does for every node
        WORLD.nodes.append(self)

    def get_name(self) -> str:
        return self._name

    def get_namespace(self) -> str:
        return self._namespace

    def get_fully_qualified_name(self) -> str:
        return f"{self._namespace.rstrip('/')}/{self._name}"

    def get_logger(self) -> Logger:
        return self.logger

    def get_clock(self) -> Clock:
        return self._clock

    def resolve_topic_name(self, topic: str, *, only_expand: bool = False) -> str:
        expanded = self._expand(topic)
        if only_expand:
            return expanded
        remapped = {self._expand(k): v for k, v in self._remaps.items()}
        return self._expand(remapped[expanded]) if expanded in remapped else expanded

    def _expand(self, topic: str) -> str:
        if topic.startswith("/"):
            return topic
        if topic.startswith("~"):
            return self.get_fully_qualified_name() + topic[1:]
        return f"{self._namespace.rstrip('/')}/{topic}"

    def has_parameter(self, name: str) -> bool:
        return name in self.parameters

    def get_parameter(self, name: str) -> Parameter:
        return self.parameters[name]

    def declare_parameter(
        self, name: str, value: Any = None, descriptor: ParameterDescriptor | None = None, ignore_override: bool = False
    ) -> Parameter:
        if name in self.parameters:
            raise ParameterAlreadyDeclaredException(name)
        descriptor = ParameterDescriptor() if descriptor is None else descriptor
        descriptor.name = name
        if descriptor.type == ParameterType.PARAMETER_NOT_SET and not descriptor.dynamic_typing:
            descriptor.type = int(Parameter.Type.from_parameter_value(value))
        if not ignore_override and name in self._overrides:
            value = self._overrides[name]
        parameter = Parameter(name, value=value)
        if not descriptor.dynamic_typing and parameter.type_ != descriptor.type:
            raise InvalidParameterTypeException(parameter, Parameter.Type(descriptor.type).name)
        for span in descriptor.floating_point_range:
            if not span.from_value - 1e-9 <= value <= span.to_value + 1e-9:
                raise InvalidParameterValueException(
                    name, value, f"Parameter {name} out of range. Min: {span.from_value}, Max: {span.to_value}"
                )
        for span in descriptor.integer_range:
            off_step = span.step and (value - span.from_value) % span.step and value != span.to_value
            if not span.from_value <= value <= span.to_value or off_step:
                raise InvalidParameterValueException(
                    name, value, f"Parameter {name} out of range. Min: {span.from_value}, Max: {span.to_value}"
                )
        self.parameters[name], self.descriptors[name] = parameter, descriptor
        return parameter

    def _qos(self, kind: str, topic: str, qos_profile: QoSProfile | int, options: QoSOverridingOptions | None):
        qos = QoSProfile(depth=qos_profile) if isinstance(qos_profile, int) else QoSProfile(**vars(qos_profile))
        if options is not None:
            suffix = "" if options.entity_id is None else f"_{options.entity_id}"
            for policy in options.policy_kinds:
                key = policy.name.lower()
                default = getattr(qos, key)
                param = self.declare_parameter(
                    f"qos_overrides.{topic}.{kind}{suffix}.{key}",
                    default.name.lower() if key in _POLICY_ENUMS else default,
                    ParameterDescriptor(
                        description=f"{key} for {kind} `{topic}` with id `{options.entity_id}`", read_only=True
                    ),
                )
                value = param.value
                setattr(qos, key, _POLICY_ENUMS[key][value.upper()] if key in _POLICY_ENUMS else value)
        return qos

    def create_subscription(
        self,
        msg_type: type,
        topic: str,
        callback: Any,
        qos_profile: QoSProfile | int,
        *,
        callback_group: Any = None,
        event_callbacks: Any = None,
        qos_overriding_options: QoSOverridingOptions | None = None,
        raw: bool = False,
    ) -> Subscription:
        name = self.resolve_topic_name(topic)
        sub = Subscription(
            msg_type, name, callback, self._qos("subscription", name, qos_profile, qos_overriding_options)
        )
        self.subscriptions.append(sub)
        return sub

    def create_publisher(
        self,
        msg_type: type,
        topic: str,
        qos_profile: QoSProfile | int,
        *,
        callback_group: Any = None,
        event_callbacks: Any = None,
        qos_overriding_options: QoSOverridingOptions | None = None,
        publisher_class: Any = None,
    ) -> Publisher:
        name = self.resolve_topic_name(topic)
        pub = Publisher(msg_type, name, self._qos("publisher", name, qos_profile, qos_overriding_options))
        self.publishers.append(pub)
        return pub

    def destroy_node(self) -> None:
        self.destroyed = True


# rclpy


@dataclass
class World:
    """What the stand-in saw and what it plays: ``script`` is a list of ``(topic, message, sim_time_ns)``."""

    script: list[tuple[str, Any, int]] = field(default_factory=list)
    inits: list[list[str] | None] = field(default_factory=list)
    nodes: list[Node] = field(default_factory=list)
    remaps: dict[str, str] = field(default_factory=dict)
    params: dict[Any, Any] = field(default_factory=dict)
    sim_time: int = 0
    initialized: bool = False
    shutdown: threading.Event = field(default_factory=threading.Event)

    def set_time(self, nanoseconds: int) -> None:
        """The time the simulation publishes on ``/clock``."""
        self.sim_time = int(nanoseconds)


WORLD = World()


def init(
    *,
    args: list[str] | None = None,
    context: Any = None,
    domain_id: int | None = None,
    signal_handler_options: Any = None,
) -> None:
    if WORLD.initialized:
        raise RuntimeError("Context.init() must only be called once")
    _, WORLD.remaps, WORLD.params = parse_ros_args(list(sys.argv if args is None else args))
    WORLD.inits.append(None if args is None else list(args))
    WORLD.initialized = True
    WORLD.shutdown.clear()


def create_node(node_name: str, **kwargs: Any) -> Node:
    return Node(node_name, **kwargs)


def spin(node: Node, executor: Any = None) -> None:
    """Play the script to the node's subscriptions, then stop as Ctrl-C does (an external shutdown first ends it)."""
    for topic, msg, sim_time in WORLD.script:
        if WORLD.shutdown.is_set():
            raise ExternalShutdownException()
        WORLD.set_time(sim_time)
        for sub in node.subscriptions:
            if sub.topic_name == topic:
                sub.callback(msg)
    raise KeyboardInterrupt


def ok(*, context: Any = None) -> bool:
    return WORLD.initialized and not WORLD.shutdown.is_set()


def try_shutdown(*, context: Any = None) -> None:
    WORLD.shutdown.set()
    WORLD.initialized = False


def remove_ros_args(args: list[str] | None = None) -> list[str]:
    return parse_ros_args(list(sys.argv if args is None else args))[0]


def _module(name: str, **attrs: Any) -> types.ModuleType:
    module = types.ModuleType(name)
    module.__dict__.update(attrs)
    return module


def install(monkeypatch: Any) -> World:
    """Put the stand-in modules into ``sys.modules`` (undone with ``monkeypatch``); returns a fresh :data:`WORLD`."""
    global WORLD
    WORLD = World()
    rclpy = _module(
        "rclpy", init=init, create_node=create_node, spin=spin, ok=ok, try_shutdown=try_shutdown, shutdown=try_shutdown
    )
    modules = {
        "rclpy": rclpy,
        "rclpy.node": _module("rclpy.node", Node=Node),
        "rclpy.qos": _module(
            "rclpy.qos",
            QoSProfile=QoSProfile,
            HistoryPolicy=HistoryPolicy,
            ReliabilityPolicy=ReliabilityPolicy,
            DurabilityPolicy=DurabilityPolicy,
            QoSPolicyKind=QoSPolicyKind,
            qos_profile_sensor_data=qos_profile_sensor_data,
        ),
        "rclpy.qos_overriding_options": _module(
            "rclpy.qos_overriding_options", QoSOverridingOptions=QoSOverridingOptions
        ),
        "rclpy.parameter": _module("rclpy.parameter", Parameter=Parameter),
        "rclpy.exceptions": _module(
            "rclpy.exceptions",
            ParameterAlreadyDeclaredException=ParameterAlreadyDeclaredException,
            InvalidParameterTypeException=InvalidParameterTypeException,
            InvalidParameterValueException=InvalidParameterValueException,
        ),
        "rclpy.executors": _module("rclpy.executors", ExternalShutdownException=ExternalShutdownException),
        "rclpy.utilities": _module("rclpy.utilities", remove_ros_args=remove_ros_args),
        "rcl_interfaces": _module("rcl_interfaces"),
        "rcl_interfaces.msg": _module(
            "rcl_interfaces.msg",
            ParameterDescriptor=ParameterDescriptor,
            FloatingPointRange=FloatingPointRange,
            IntegerRange=IntegerRange,
            ParameterType=ParameterType,
        ),
    }
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    return WORLD
