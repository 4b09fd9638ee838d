"""Settings of the core's configurations from the command line: `pose4d eval --config
section.key=value` (repeatable), for the validation sweeps of `make results`.

Sections are the configurations the offline pipeline builds: `foreground`
(`core.foreground.ForegroundConfig`), `search` (`core.dpm.infer.SearchConfig`), `scale`
(`core.dpm.scale.ScaleConfig`), `slqe` (`core.slqe.SlqeConfig`), `tracking`
(`core.people.TrackingConfig`) and `unary` (`core.dpm.net_unary.UnaryConfig`, with `pose4d
eval --colour-net`). A value is read as the
type of the field's default: a number, a boolean (true/false), a string, or a comma list for a
tuple (of numbers or of names). The configuration checks the result as it checks any value.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any, TypeVar

from pose4d_ros.core.dpm.infer import SearchConfig
from pose4d_ros.core.dpm.net_unary import UnaryConfig
from pose4d_ros.core.dpm.scale import ScaleConfig
from pose4d_ros.core.foreground import ForegroundConfig
from pose4d_ros.core.people import TrackingConfig
from pose4d_ros.core.slqe import SlqeConfig

SECTIONS: dict[str, type] = {'foreground': ForegroundConfig, 'search': SearchConfig,
                             'scale': ScaleConfig, 'slqe': SlqeConfig,
                             'tracking': TrackingConfig, 'unary': UnaryConfig}
C = TypeVar('C')


def _value(text: str, default: Any, where: str) -> Any:
    if isinstance(default, bool):
        if text.lower() not in ('true', 'false', '1', '0'):
            raise ValueError(f'{where}: {text!r} is not true or false')
        return text.lower() in ('true', '1')
    if isinstance(default, tuple):
        items = [t.strip() for t in text.split(',') if t.strip()]
        kind = type(default[0]) if default else str
        return tuple(_value(t, kind(), where) for t in items)
    try:
        return type(default)(text)
    except (TypeError, ValueError):
        raise ValueError(f'{where}: {text!r} is not a {type(default).__name__}') from None


def parse(items: Iterable[str]) -> dict[str, dict[str, Any]]:
    """'section.key=value' items -> {section: {key: value}} (typed, not yet checked)."""
    out: dict[str, dict[str, Any]] = {}
    for item in items:
        name, sep, text = item.partition('=')
        section, dot, key = name.strip().partition('.')
        if not sep or not dot:
            raise ValueError(f'--config {item!r}: expected section.key=value')
        if section not in SECTIONS:
            raise ValueError(f'--config {item!r}: no section {section!r} (sections: '
                             f'{", ".join(SECTIONS)})')
        fields = {f.name: f for f in dataclasses.fields(SECTIONS[section])}
        if key not in fields:
            raise ValueError(f'--config {item!r}: {SECTIONS[section].__name__} has no '
                             f'{key!r} (fields: {", ".join(fields)})')
        default = getattr(SECTIONS[section](), key)
        out.setdefault(section, {})[key] = _value(text.strip(), default, f'--config {item}')
    return out


def apply(config: C, settings: dict[str, dict[str, Any]], section: str) -> C:
    """`config` with `settings[section]`'s values (the config's own checks run)."""
    values = settings.get(section)
    return dataclasses.replace(config, **values) if values else config
