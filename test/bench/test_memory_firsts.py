"""bench/memory.py's figures of a hit's first motion (``publish: first_then_optimum``).

From the statuses the bench collects per request: the first motion's latency and ``T`` are
summarised over the hits that published one (a hit without one, a miss, are left out), the
``T`` gap taken against the request's final motion.
"""

from __future__ import annotations

import sys
from pathlib import Path

# The repository, for bench/ (not installed), last: tocontrol_ros stays the installed one.
sys.path.append(str(Path(__file__).resolve().parents[2]))

from bench.memory import first_motions  # noqa: E402


def _hit(latency, T_first, T, iteration=None):
    values = {"memory": "hit", "T": str(T)}
    if latency is not None:
        values.update(first_latency=str(latency), first_T=str(T_first),
                      memory_first_iteration=str(iteration))
    return {"first": (1.0, values)}


def test_the_first_motions_are_summarised_over_the_hits_that_published_one():
    hits = [_hit(0.2, 1.01, 1.0, 0), _hit(0.4, 1.03, 1.0, 12), _hit(None, None, 1.0)]
    text = first_motions({"hits": hits})
    assert "on 2/3 hits" in text
    assert "moved onto the request on 1, a certified IPOPT iterate on 1" in text
    assert "median 300 ms" in text
    assert "median 2.00 %" in text and "worst 3.00 %" in text


def test_no_first_motion_at_all_is_said_and_not_an_error():
    text = first_motions({"hits": [_hit(None, None, 1.0)]})
    assert "on 0/1 hits" in text and "nan" in text
