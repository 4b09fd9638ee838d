"""Declared, described and validated node parameters, some of them settable while running.

Each node lists its parameters once as `Param` specs. `NodeParams` declares them with a
`ParameterDescriptor` (description, range, read-only) and validates the start-up values, refusing
a bad one with a message that names the parameter, the value and the rule. A `live` parameter
(a threshold, a gate, a noise level, a rate, TF on/off) can be changed while the node runs
(`ros2 param set`): the same rules validate the new value, and the node takes it up before its
next message (`NodeParams.changes`). The others are read-only, and their description says why a
change needs a restart. `config/<node>.yaml` holds the same defaults (a test checks).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

Value = bool | int | float | str | list[str] | list[float]


class ParameterError(ValueError):
    """A parameter value was refused; the message names the parameter and the rule."""


@dataclass(frozen=True)
class Param:
    """One node parameter.

    `range` is inclusive (numbers); `choices` restricts strings; `check` is an extra rule that
    returns an error text or None. Either `live` (settable while the node runs) or read-only,
    with `restart` saying why a change needs a restart.
    """

    name: str
    default: Value
    description: str
    range: tuple[float, float] | None = None
    choices: tuple[str, ...] | None = None
    check: Callable[[Any], str | None] | None = None
    live: bool = False
    restart: str = ''

    def __post_init__(self) -> None:
        if self.live == bool(self.restart):
            raise TypeError(f'{self.name}: a parameter is either live or says why a change '
                            'needs a restart')

    def descriptor(self) -> ParameterDescriptor:
        text = self.description
        if self.choices:
            text += f' One of: {", ".join(self.choices)}.'
        text += (' Settable while running (ros2 param set), used from the next message on.'
                 if self.live else f' Read-only while running: {self.restart}.')
        d = ParameterDescriptor(description=text, read_only=not self.live)
        if self.range is not None:
            lo, hi = self.range
            if isinstance(self.default, bool):
                raise TypeError(f'{self.name}: a bool parameter takes no range')
            if isinstance(self.default, int):
                d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=0)]
            else:
                d.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                             to_value=float(hi), step=0.0)]
        if self.choices:
            d.additional_constraints = f'one of {list(self.choices)}'
        return d

    def validate(self, value: Any) -> str | None:
        """Why `value` is refused, or None if it is fine."""
        if self.range is not None and not (self.range[0] <= value <= self.range[1]):
            return f'{value!r} is outside [{self.range[0]}, {self.range[1]}]'
        if self.choices is not None and value not in self.choices:
            return f'{value!r} is not one of {list(self.choices)}'
        if self.check is not None:
            return self.check(value)
        return None


class NodeParams:
    """A node's parameters, declared and validated; live ones follow `ros2 param set`.

    `values` holds the current value of each parameter by name. A set request is refused with
    the rule it breaks (rclpy itself refuses read-only parameters, other types and values out of
    range; `check(values)`, which builds the node's settings, raises ValueError for values that
    break the core's rules together); an accepted one updates `values` and is reported once by
    `changes()`, which the node calls before each message it processes, so a change takes
    effect between two frames. Raises ParameterError for start-up values that break a rule.
    """

    def __init__(self, node: Node, params: Sequence[Param],
                 check: Callable[[dict[str, Any]], object] | None = None) -> None:
        self._specs = {p.name: p for p in params}
        values: dict[str, Any] = {}
        for p in params:
            try:
                param = node.declare_parameter(p.name, p.default, p.descriptor())
            except Exception as exc:  # rclpy's InvalidParameterValue/TypeException
                raise ParameterError(f'parameter {p.name}: {exc}') from None
            values[p.name] = _plain(param.value)
            problem = p.validate(values[p.name])
            if problem:
                raise ParameterError(f'parameter {p.name}: {problem}')
        self._check_all = check
        if problem := self._problem(values):
            raise ParameterError(problem)
        self.values: dict[str, Any] = values
        self._changed = False
        node.add_on_set_parameters_callback(self._check)
        node.add_post_set_parameters_callback(self._store)

    def changes(self) -> dict[str, Any] | None:
        """The values, if a parameter changed since the last call; else None."""
        if not self._changed:
            return None
        self._changed = False
        return self.values

    def _problem(self, values: dict[str, Any]) -> str | None:
        """Why the values together break the node's rules, or None."""
        if self._check_all is None:
            return None
        try:
            self._check_all(values)
        except ValueError as exc:
            return f'parameters refused: {exc}'
        return None

    def _check(self, parameters: list[Parameter]) -> SetParametersResult:
        for param in parameters:
            spec = self._specs.get(param.name)
            problem = spec.validate(_plain(param.value)) if spec is not None else None
            if problem:
                return SetParametersResult(successful=False,
                                           reason=f'parameter {param.name}: {problem}')
        problem = self._problem({**self.values, **{p.name: _plain(p.value) for p in parameters
                                                   if p.name in self._specs}})
        return SetParametersResult(successful=problem is None, reason=problem or '')

    def _store(self, parameters: list[Parameter]) -> None:
        ours = {p.name: _plain(p.value) for p in parameters if p.name in self._specs}
        if ours:
            self.values = {**self.values, **ours}  # one assignment: readers see old or new
            self._changed = True


def _plain(value: Any) -> Any:
    return list(value) if isinstance(value, list | tuple) else value


def override_args(params: Mapping[str, Value]) -> list[str]:
    """`-p name:=value` command-line overrides (after `--ros-args`) for `params`: values
    written as JSON, which the ROS argument parser reads as YAML of the same types (strings
    quoted, so '*', ':' or ',' in them stay text; 1.0 stays a double)."""
    return [arg for name, value in params.items()
            for arg in ('-p', f'{name}:={json.dumps(value)}')]
