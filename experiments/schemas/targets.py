"""Schemas of ``_target_`` blocks, derived from the target's own signature.

A block such as ``planner`` (``_target_: decpomdp.search.PlannerConfig``) is typed by the parameters of
its target: :func:`target_schema` builds a dataclass with ``_target_`` and one field per
parameter (its annotation when it is a plain ``int``/``float``/``bool``/``str``, optionally
``None``; ``Any`` otherwise), so Hydra rejects a wrong type or an unknown key when it composes.
Ranges are checked by the target itself: :meth:`TargetBlock.check` instantiates it (with
``overrides`` for arguments supplied at run time) and reports its error under the block's key.
"""

from __future__ import annotations

import dataclasses
import inspect
import types
import typing
from typing import Any, Optional

from hydra.utils import get_object, instantiate

_PLAIN = (int, float, bool, str)


def _field_type(hint: Any) -> Any:
    """The OmegaConf type of a parameter annotation: plain types (optionally None), else ``Any``."""
    if hint in _PLAIN:
        return hint
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) == 1 and args[0] in _PLAIN and len(typing.get_args(hint)) == 2:
            return Optional[args[0]]
    return Any


class TargetBlock:
    """Base of the generated schemas: ``check`` builds the target to run its own validation."""

    _runtime: tuple[str, ...] = ()  # parameters supplied when the experiment instantiates the block

    def check(self, path: str) -> None:
        kwargs = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for name in self._runtime:
            kwargs.pop(name, None)
        try:
            instantiate(kwargs)
        except Exception as exc:  # the target's own message names the argument
            cause = exc.__cause__ if exc.__cause__ is not None else exc
            raise ValueError(join_key(path, str(cause), kwargs)) from None


def join_key(path: str, message: str, fields: Any = ()) -> str:
    """``"path.field: ..."`` when ``message`` starts with one of ``fields``, else ``"path: message"``."""
    head = message.split(":", 1)[0]
    if head in fields:
        return f"{path}.{message}"
    return f"{path}: {message}"


def _as_lists(value: Any) -> Any:
    """Nested tuples and lists as nested lists."""
    return [_as_lists(v) for v in value] if isinstance(value, (list, tuple)) else value


def signature_defaults(obj: Any) -> dict[str, Any]:
    """The default of every parameter of a function or a class's ``__init__`` that has one."""
    init = obj.__init__ if inspect.isclass(obj) else obj
    return {k: p.default for k, p in inspect.signature(init).parameters.items() if p.default is not p.empty}


def preset(target: str, config: Any, **fields: Any) -> dict[str, Any]:
    """A config node for a dataclass instance ``config`` of ``target``: ``_target_`` and the fields that differ
    from the target's defaults (sequences as lists), then ``fields`` (e.g. interpolations) over them."""
    defaults = signature_defaults(get_object(target))
    node: dict[str, Any] = {"_target_": target}
    for f in dataclasses.fields(config):
        value = _as_lists(getattr(config, f.name))
        if f.name not in defaults or _as_lists(defaults[f.name]) != value:
            node[f.name] = value
    return {**node, **fields}


def target_schema(target: str, runtime: tuple[str, ...] = ()) -> type:
    """A dataclass schema for a ``_target_: <target>`` block (see the module docstring).

    Args:
        target: dotted path of a class or function.
        runtime: parameters the experiment passes at instantiation (left out of the range check).
    """
    obj = get_object(target)
    init = obj.__init__ if inspect.isclass(obj) else obj
    hints = typing.get_type_hints(init)
    fields: list[tuple[str, Any, Any]] = [("_target_", str, dataclasses.field(default=target))]
    for name, param in inspect.signature(init).parameters.items():
        if name == "self" or param.kind in (param.VAR_POSITIONAL, param.VAR_KEYWORD):
            continue
        default = None if param.default is inspect.Parameter.empty else param.default
        if isinstance(default, (list, tuple)):  # a sequence default (lists of lists in the config)
            spec = dataclasses.field(default_factory=lambda d=default: _as_lists(d))
        else:
            spec = dataclasses.field(default=default if default is None or isinstance(default, _PLAIN) else None)
        fields.append((name, _field_type(hints.get(name, Any)), spec))
    name = target.rsplit(".", 1)[-1] + "Block"
    return dataclasses.make_dataclass(name, fields, bases=(TargetBlock,), namespace={"_runtime": runtime})
