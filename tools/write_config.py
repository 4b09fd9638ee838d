"""Write config/<node>.yaml from a node module's PARAMS (the code holds the defaults).

    PYTHONPATH=. .venv/bin/python tools/write_config.py tracker ik ...

A test checks that every config file equals its node's defaults, so run this after changing a
parameter (with `PYTHONPATH=.`, the source tree's PARAMS: the venv's copy of the package is
the one `make` last installed).
"""

import importlib
import sys
from pathlib import Path

import yaml

CONFIG = Path(__file__).resolve().parents[1] / 'config'


def _value(v: object) -> str:
    return yaml.safe_dump(v, default_flow_style=True).strip().removesuffix('\n...')


def render(node: str, params: tuple) -> str:
    lines = [f'# ros2 run pose4d_ros {node} --ros-args --params-file config/{node}.yaml',
             f'{node}:', '  ros__parameters:']
    groups: dict[str, list] = {}
    for p in params:
        group, _, key = p.name.rpartition('.')
        groups.setdefault(group, []).append((key, p))
    for group, items in groups.items():
        indent = '    '
        if group:
            lines.append(f'    {group}:')
            indent = '      '
        for key, p in items:
            desc = p.description.rstrip('.')
            lines.append(f'{indent}{key}: {_value(p.default)}  # {desc}')
    return '\n'.join(lines) + '\n'


def main(nodes: list[str]) -> int:
    for node in nodes:
        module = importlib.import_module(f'pose4d_ros.nodes.{node}')
        (CONFIG / f'{node}.yaml').write_text(render(node, module.PARAMS))
        print(f'wrote config/{node}.yaml')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
