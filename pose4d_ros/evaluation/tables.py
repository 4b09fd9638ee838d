"""The paper's tables: the models a source is scored with by default, and the scores as text and
as JSON rows."""

from __future__ import annotations

import numpy as np

from pose4d_ros.core.convnet import ConvNet, is_convnet, load_convnet
from pose4d_ros.core.dpm.model import PartModel, load_model
from pose4d_ros.core.dpm.net_unary import NetUnary, UnaryConfig
from pose4d_ros.core.skeleton import JOINT_GROUPS
from pose4d_ros.evaluation.tracking_metrics import SEEN_BINS
from pose4d_ros.models import DEFAULT_COLOUR_NET, DEFAULT_NET_PRECISION, model_path

TABLE_METRICS = (('pck', 'PCK@0.1 (%)'), ('pck@0.2', 'PCK@0.2 (%)'), ('apk', 'APK (%)'),
                 ('error_px', 'error (px)'), ('error_mm', '3-D median error (mm)'),
                 ('within_10cm', '3-D within 10 cm (%)'))


def format_table(rows: dict[str, dict[str, dict[str, float]]], frames: int) -> str:
    """The rows as text: one block per metric (those some row has), groups as columns; '-'
    where a row has no value, 'inf' for a median that more than half the joints miss."""
    groups = [g for g in JOINT_GROUPS if any(g in r['pck'] for r in rows.values())]
    cols = groups + ['average', 'average7']
    width = max(14, *(len(name) + 2 for name in rows))
    lines = [f'{frames} frames']
    for key, title in TABLE_METRICS:
        if not any(key in row for row in rows.values()):
            continue
        shown = [c for c in cols if any(c in row.get(key, {}) for row in rows.values())]
        lines += ['', title, ' ' * width + ''.join(f'{c:>10}' for c in shown)]
        for name, row in rows.items():
            vals = row.get(key, {})
            lines.append(f'{name:<{width}}' + ''.join(
                f'{vals[c]:>10.1f}' if c in vals and not np.isnan(vals[c]) else f'{"-":>10}'
                for c in shown))
    if any('tracking' in row for row in rows.values()):
        keys = ('idf1', 'mota', 'id_switches_per_1000', 'missed_per_1000', 'false_per_1000')
        heads = ('IDF1 %', 'MOTA %', 'IDsw/1k', 'miss/1k', 'false/1k')
        lines += ['', 'Tracking (several people; per 1000 person-frames, false per 1000 frames)',
                  ' ' * width + ''.join(f'{h:>10}' for h in heads)]
        for name, row in rows.items():
            t = row.get('tracking', {})
            lines.append(f'{name:<{width}}' + ''.join(
                f'{t[k] * (100 if k in ("idf1", "mota") else 1):>10.1f}'
                if k in t and np.isfinite(t[k]) else f'{"-":>10}' for k in keys))
    if any('seen' in row for row in rows.values()):
        bins = [label for label, *_ in SEEN_BINS]
        lines += ['', 'PCK@0.1 average7 by how much of the person the depth shows (share of the '
                  'person-frames)', ' ' * width + ''.join(f'{SEEN_HEADS[b]:>18}' for b in bins)]
        for name, row in rows.items():
            seen = row.get('seen')
            if seen:
                lines.append(f'{name:<{width}}' + ''.join(
                    f"{_num(seen[f'average7_{b}'])} ({_num(100 * seen[f'share_{b}'])} %)"
                    .rjust(18) for b in bins))
    if any('cpu_ms' in row for row in rows.values()):
        lines += ['', 'CPU per frame (ms)', ' ' * width + f'{"p50":>10}{"p95":>10}']
        lines += [f'{name:<{width}}' + ''.join(
            f'{row["cpu_ms"][k]:>10.1f}' if row['cpu_ms'][k] is not None else f'{"-":>10}'
            for k in ('p50', 'p95')) for name, row in rows.items() if 'cpu_ms' in row]
    return '\n'.join(lines)


SEEN_HEADS = {'80': '>= 80 % seen', '50_80': '50-80 % seen', 'under_50': '< 50 % seen'}


def _num(v: float | None) -> str:
    return '-' if v is None or not np.isfinite(v) else f'{v:.1f}'


def clean_row(table: dict[str, dict[str, float]]) -> dict[str, dict[str, float | None]]:
    """The row in the JSON's order (`TABLE_METRICS`, then cpu_ms), NaN and infinity as null."""
    order = [k for k, _ in TABLE_METRICS] + [k for k in table if k not in dict(TABLE_METRICS)]
    return {k: {g: (round(float(v), 3) if v is not None and np.isfinite(v) else None)
                for g, v in table[k].items()} for k in order if k in table}


def default_models(kind: str) -> list[str]:
    """The models `pose4d eval` runs on a source of `kind` (`datasets.sources.source_kind`):
    the nodes' `rgbd_14` alone on a real recording (a folder of frames)."""
    return {'lspet': ['lspet_convnet'], 'frames': ['rgbd_14']}.get(kind, ['rgbd_14', 'rgb_10'])


def load_any(name: str, precision: str = DEFAULT_NET_PRECISION) -> PartModel | ConvNet:
    """A part model or a photograph network (`core.convnet`, run at `precision`), by shipped
    name or path."""
    path = model_path(name)
    return load_convnet(path, precision) if is_convnet(path) else load_model(path)


def colour_unary(name: str = DEFAULT_COLOUR_NET, precision: str = DEFAULT_NET_PRECISION,
                 config: UnaryConfig | None = None) -> NetUnary | None:
    """The photograph network `name` as the part models' colour unary, as the detector node
    runs it by default (`detector.colour_net`, `detector.colour_net_precision`); None for
    'none'. ValueError when `name` is a part model."""
    if name == 'none':
        return None
    net = load_any(name, precision)
    if not isinstance(net, ConvNet):
        raise ValueError(f'{name}: not a photograph network')
    return NetUnary(net, config or UnaryConfig())
