"""A short fuzz of every input-consuming node (`make fuzz` is the long one: test/fuzz.py)."""

from __future__ import annotations

import pytest
from fuzz import NODES, fuzz_node


@pytest.mark.parametrize('name', NODES)
def test_node_survives_malformed_messages(name, tmp_path):
    res = fuzz_node(name, 150, tmp_path, seed=1)
    assert res['sent'] == 150
    assert (res['crashes'], res['hangs'], res['liveness_failures']) == (0, 0, 0), res
    # the malformed frames reached the node's checks: it refused and counted most of them
    # (counted over the fuzz alone: the warm-up's malformed frames are subtracted)
    refused = sum(d['bad_inputs'] for d in res['fuzz_counts'].values())
    assert refused >= 0.5 * res['sent'], res['fuzz_counts']
    # bytes that do not deserialize are sent too, and refused like the rest
    assert sum(n for kind, n in res['kinds'].items() if kind.startswith('raw_')) >= 10, res
