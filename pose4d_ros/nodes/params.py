"""Declared, described and validated node parameters.

Each node lists its parameters once as `Param` specs; `declare` declares them with a
`ParameterDescriptor` (description, range, read-only) and validates the start-up values, refusing
a bad one with a message that names the parameter, the value and the rule, and returns them.
`config/<node>.yaml` holds the same defaults (a test checks).
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
)
from rclpy.node import Node

Value = bool | int | float | str | list[str]


class ParameterError(ValueError):
    """A parameter value was refused; the message names the parameter and the rule."""


@dataclass(frozen=True)
class Param:
    """One node parameter.

    `range` is inclusive (numbers); `choices` restricts strings; `check` is an extra rule that
    returns an error text or None. Parameters are read-only: read once at start-up.
    """

    name: str
    default: Value
    description: str
    range: tuple[float, float] | None = None
    choices: tuple[str, ...] | None = None
    check: Callable[[Any], str | None] | None = None

    def descriptor(self) -> ParameterDescriptor:
        text = self.description
        if self.choices:
            text += f' One of: {", ".join(self.choices)}.'
        d = ParameterDescriptor(description=text, read_only=True)
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


def declare(node: Node, params: Sequence[Param]) -> dict[str, Any]:
    """Declare and validate `params` on `node`; return {name: value}.

    Raises ParameterError for a start-up value that breaks a rule (rclpy's own type and range
    checks raise their exceptions, which `common.run` reports the same way).
    """
    values: dict[str, Any] = {}
    for p in params:
        try:
            param = node.declare_parameter(p.name, p.default, p.descriptor())
        except Exception as exc:  # rclpy's InvalidParameterValue/TypeException
            raise ParameterError(f'parameter {p.name}: {exc}') from None
        value = param.value
        if isinstance(value, list | tuple) and not isinstance(value, str):
            value = list(value)
        problem = p.validate(value)
        if problem:
            raise ParameterError(f'parameter {p.name}: {problem}')
        values[p.name] = value
    return values


def override_args(params: Mapping[str, Value]) -> list[str]:
    """`-p name:=value` command-line overrides (after `--ros-args`) for `params`: values
    written as JSON, which the ROS argument parser reads as YAML of the same types (strings
    quoted, so '*', ':' or ',' in them stay text; 1.0 stays a double)."""
    return [arg for name, value in params.items()
            for arg in ('-p', f'{name}:={json.dumps(value)}')]
