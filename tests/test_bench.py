"""The benchmark harness (experiments/bench.py): the three implementations are timed
side by side in rounds, and what it reports comes from those calls.  No timing is
asserted here, only the bookkeeping: call counts, rounds, ratios and agreement."""

from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "experiments"))
import bench


def test_interleaved_rounds_call_every_implementation_in_every_round():
    calls = []

    def fn(name, value):
        def f():
            calls.append(name)
            return value
        return f

    fns = {"a": fn("a", 1), "b": fn("b", 2), "c": fn("c", 3)}
    times, outs, rounds = bench.time_interleaved(fns, min_rounds=3, max_rounds=4, budget_s=0.0)
    assert len(rounds) == 3  # the budget is reached at once: the minimum number of rounds
    assert outs == {"a": 1, "b": 2, "c": 3}
    assert all(set(r) == {"a", "b", "c"} for r in rounds)
    # one sizing call each, then every round visits a, b, c in turn (each 1..max_rounds // min_rounds times)
    assert calls[:3] == ["a", "b", "c"]
    runs = [name for i, name in enumerate(calls[3:]) if i == 0 or calls[3 + i - 1] != name]
    assert runs == ["a", "b", "c"] * 3
    for name in fns:
        assert len(times[name]) == calls.count(name) - 1 == len(times[name].cpu)
        assert 3 <= len(times[name]) <= 3 * (4 // 3)

    times, _, rounds = bench.time_interleaved(fns, min_rounds=1, max_rounds=5, budget_s=1e9)
    assert len(rounds) == 5  # the budget is never reached: stops at max_rounds


def test_measure_config_reports_the_side_by_side_ratios():
    args = bench.parse_args(["--quick", "--min-repeats", "2", "--repeats", "4"])
    args.time_budget = args.numpy_seconds = 0.0
    rec = bench.measure_config(8, 64, 8, args)
    assert rec["agree"] and rec["max_rel_diff"] <= bench.TOLERANCE
    assert rec["rounds"] >= 2
    for name in ("kernel", "naive_vmap", "numpy"):
        assert rec[name]["repeats"] >= rec["rounds"]
        assert rec[name]["evals_per_s"] > 0
    k, nv, nu = (rec[n]["evals_per_s"] for n in ("kernel", "naive_vmap", "numpy"))
    assert np.isclose(rec["kernel_vs_numpy"], k / nu) and np.isclose(rec["kernel_vs_naive_vmap"], k / nv)
    for key in ("kernel_vs_numpy", "kernel_vs_naive_vmap"):
        lo, med, hi = rec["ratio_range"][key]
        assert 0 < lo <= med <= hi
    assert "rounds:" not in bench.round_ranges({}) and f"over {rec['rounds']} rounds" in bench.round_ranges(rec)
