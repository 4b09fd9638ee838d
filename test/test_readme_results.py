"""The README's results summary is what `pose4d results` wrote to docs/results: every figure in
its table is checked against the JSON, so none can drift from what the code produced."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from pose4d_ros.evaluation import results_doc as doc

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / 'docs' / 'results'


def summary_block(text: str) -> str:
    assert doc.SUMMARY_BEGIN in text and doc.SUMMARY_END in text, 'README has no results summary'
    return text.split(doc.SUMMARY_BEGIN, 1)[1].split(doc.SUMMARY_END, 1)[0]


def parse_table(block: str) -> tuple[list[str], dict[str, list[str]]]:
    """The summary table's set titles and, per row key, its cells."""
    lines = [ln for ln in block.splitlines() if ln.startswith('|')]
    head = [c.strip() for c in lines[0].strip('|').split('|')][1:]
    rows = {}
    for ln in lines[2:]:
        cells = [c.strip() for c in ln.strip('|').split('|')]
        key = re.match(r'`([^`]+)`', cells[0])
        assert key, f'a summary row without its key: {ln}'
        rows[key.group(1)] = cells[1:]
    return head, rows


def test_every_figure_of_the_readme_summary_is_the_jsons() -> None:
    block = summary_block((ROOT / 'README.md').read_text())
    titles, rows = parse_table(block)
    sets = [s for s, t in doc.SUMMARY_SETS if (RESULTS / f'{s}.json').exists()]
    assert sets, 'no docs/results/*.json for the summary (run `make results`)'
    tables = {s: json.loads((RESULTS / f'{s}.json').read_text()) for s in sets}
    title = dict(doc.SUMMARY_SETS)
    assert titles == [f'{title[s]} ({tables[s]["frames"]})' for s in sets]
    assert rows, 'the summary has no rows'
    for key, cells in rows.items():
        for s, c in zip(sets, cells, strict=True):
            row = tables[s]['rows'].get(key)
            assert c == (doc.cell(row) if row else '-'), f'{key} on {s}: README {c!r}'
    # and every row the JSON has for the summary is shown
    for key, _ in doc.SUMMARY_ROWS:
        if any(key in tables[s]['rows'] for s in sets):
            assert key in rows, f'{key} is in docs/results but not in the README summary'
    for name, pattern in (('bench', r'MediaPipe \(p50, same run, demo bag\): ([0-9.]+[0-9])'),
                          ('bench_people', r'every person region searched\): ([0-9.]+[0-9])')):
        bench = RESULTS / f'{name}.json'
        ratio = re.search(pattern, block)
        if bench.exists() and 'ratio_to_peer' in json.loads(bench.read_text()):
            assert ratio and float(ratio.group(1)) == pytest.approx(
                json.loads(bench.read_text())['ratio_to_peer'], abs=5e-4), name
        else:
            assert ratio is None, name


def _deployed_figures(stem: str, pattern: str, skip_why: str, missing: str
                      ) -> tuple[str, list[float], dict]:
    """The README summary, the figures `pattern` reads in it and the `graph` of
    `docs/results/<stem>.json`: a summary without MediaPipe in that JSON gives none (the test
    is skipped, `skip_why`), one with it must give them (else it fails, `missing`)."""
    block = summary_block((ROOT / 'README.md').read_text())
    path = RESULTS / f'{stem}.json'
    graph = json.loads(path.read_text()).get('graph', {}) if path.exists() else {}
    found = re.search(pattern, block, re.S)
    if 'peer_ms_per_frame' not in graph:
        assert found is None
        pytest.skip(skip_why)
    assert found, missing
    return block, [float(x) for x in found.groups()], graph


def test_the_headline_cost_is_the_deployed_graphs() -> None:
    """The README's first CPU figure is the node graph's as deployed, against MediaPipe in the
    same run, as `docs/results/bench_graph300.json` holds it."""
    block, figures, graph = _deployed_figures(
        'bench_graph300', r'CPU per frame as deployed.*?the four stage nodes together ([0-9.]+) '
        r"ms = ([0-9.]+)x MediaPipe's ([0-9.]+) ms.*?the one-process `pipeline` node "
        r'([0-9.]+) ms = ([0-9.]+)x MediaPipe',
        'docs/results/bench_graph300.json has no MediaPipe (make peer, then make results '
        'RESULTS_ONLY=bench_graph300)', 'the README summary does not give the deployed cost')
    nodes, one = graph['nodes'], graph['pipeline']
    assert figures == pytest.approx(
        [nodes['stages_ms_per_frame'], nodes['to_peer'], graph['peer_ms_per_frame'],
         one['stages_ms_per_frame'], one['to_peer']], abs=5e-3)
    _composed_figures(block, 'composed in one process.*?composed`\\) ([0-9.]+) ms = '
                      '([0-9.]+)x MediaPipe, ([0-9.]+)x the core', graph, 'to_peer')
    # it comes before the core's own ratio
    assert block.index('as deployed') < block.index('in one process (the core)')


def test_the_quiet_deployed_cost_is_its_json() -> None:
    """Beside the headline, the same graphs with nothing else running, as
    `docs/results/bench_graph300_quiet.json` holds them."""
    block, figures, graph = _deployed_figures(
        'bench_graph300_quiet', r'With nothing else running.*?the four stage nodes ([0-9.]+) ms '
        r'= ([0-9.]+)x the core \(([0-9.]+) ms\), ([0-9.]+)x MediaPipe.*?`pipeline` ([0-9.]+) '
        r'ms = ([0-9.]+)x the core',
        'docs/results/bench_graph300_quiet.json has no MediaPipe',
        'the README summary does not give the quiet deployed cost')
    nodes, one = graph['nodes'], graph['pipeline']
    assert figures == pytest.approx(
        [nodes['stages_ms_per_frame'], nodes['to_core'], graph['core_ms_per_frame']['total'],
         nodes['to_peer'], one['stages_ms_per_frame'], one['to_core']], abs=5e-3)
    quiet = block[block.index('With nothing else running'):]
    _composed_figures(quiet, 'composed ([0-9.]+) ms = ([0-9.]+)x the core, ([0-9.]+)x '
                      'MediaPipe', graph, 'to_core')


def _composed_figures(text: str, pattern: str, graph: dict, second: str) -> None:
    """The composed graph's figures in `text` (CPU, then `second` and the other ratio) are
    its JSON's; a bench from before it (no `composed`) gives none."""
    found = re.search(pattern, text, re.S)
    if 'composed' not in graph:
        assert found is None
        return
    both = graph['composed']
    third = 'to_core' if second == 'to_peer' else 'to_peer'
    assert found, 'the README summary does not give the composed graph'
    assert [float(x) for x in found.groups()] == pytest.approx(
        [both['stages_ms_per_frame'], both[second], both[third]], abs=5e-3)


def test_the_summary_is_what_the_generator_writes() -> None:
    block = summary_block((ROOT / 'README.md').read_text())
    assert block.strip() == doc.summary(RESULTS).strip()


def test_a_drifted_figure_fails(tmp_path: Path) -> None:
    results = tmp_path / 'results'
    results.mkdir()
    row = {'pck': {'average7': 96.04}, 'within_10cm': {'average': 90.46}}
    (results / 'test.json').write_text(json.dumps({'frames': 400, 'rows': {'rgbd_kf': row}}))
    readme = tmp_path / 'README.md'
    readme.write_text(f'x\n{doc.SUMMARY_BEGIN}\nold\n{doc.SUMMARY_END}\ny\n')
    assert doc.update_readme(readme, results)
    titles, rows = parse_table(summary_block(readme.read_text()))
    assert titles == ['test (400)'] and rows == {'rgbd_kf': ['96.0 / 90.5']}
    assert readme.read_text().startswith('x\n') and readme.read_text().endswith('y\n')


def test_the_cost_of_each_person_past_the_first_is_their_share_of_the_first_s_total() -> None:
    def group(frames: int, total: float) -> dict:
        return {'frames': frames, 'total': {'p50': total},
                **{k: {'p50': total / 4} for k in ('foreground', 'detector', 'tracker', 'ik')}}
    bench = {'people_ms': {'1': group(40, 10.0), '2': group(100, 16.0), '3': group(60, 24.0)}}
    rows = [line for line in doc.people_cost_section(bench, None) if line.startswith('| ')]
    assert rows[1:] == ['| 1 | 40 | 2.5 | 2.5 | 2.5 | 2.5 | 10.0 |  |',
                        '| 2 | 100 | 4.0 | 4.0 | 4.0 | 4.0 | 16.0 | 0.60 |',
                        '| 3 | 60 | 6.0 | 6.0 | 6.0 | 6.0 | 24.0 | 0.70 |']
    # no frame with one person: the first's total from the fewest seen, 2 and 3 here
    # (8 a person past the first, the first 16 - 8 = 8: 1.00)
    bench = {'people_ms': {'0': group(5, 1.0), '2': group(100, 16.0), '3': group(60, 24.0)}}
    rows = [line for line in doc.people_cost_section(bench, None) if line.startswith('| ')]
    assert [r.split(' | ')[0] for r in rows[1:]] == ['| 2', '| 3']
    assert rows[-1].endswith('| 1.00 |')
    assert doc.people_cost_section({'stages_ms': {}}, None) == []
