"""diagnosis.memo.Memo: the bounded memo the real-rig replays and the disturbance estimates share."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from maglev_cosim.diagnosis.memo import Memo


def test_a_kept_result_is_not_computed_again_and_the_least_recently_used_goes_first():
    m, calls = Memo(2), []

    def make(k):
        return lambda: calls.append(k) or f"value {k}"

    assert m.get("a", make("a")) == "value a"
    assert m.get("b", make("b")) == "value b"
    assert m.get("a", make("a")) == "value a"      # kept: not computed again, and now the most recent
    assert m.get("c", make("c")) == "value c"      # pushes out b, the least recently used
    assert m.get("a", make("a")) == "value a"
    assert m.get("b", make("b")) == "value b"      # computed again
    assert calls == ["a", "b", "c", "b"] and len(m) == 2
    m.clear()
    assert len(m) == 0


def test_a_result_the_check_refuses_is_computed_again_and_a_fresh_one_is_sealed():
    m = Memo(4)
    first = m.get("k", lambda: ("old", np.zeros(3)), seal=lambda out: setattr(out[1].flags, "writeable", False))
    assert not first[1].flags.writeable
    again = m.get("k", lambda: ("new", np.ones(3)), valid=lambda hit: hit[0] == "new")
    assert again[0] == "new"
    assert m.get("k", lambda: ("newer", None), valid=lambda hit: hit[0] == "new") is again


def test_threads_share_the_kept_results():
    m = Memo(8)
    m.get(1, lambda: object())
    with ThreadPoolExecutor(4) as ex:
        got = list(ex.map(lambda _: m.get(1, lambda: object()), range(16)))
    assert all(g is got[0] for g in got)
