"""The benchmark harness (experiments/bench.py, bench_kernel.py, bench_timing.py): the three
implementations are timed side by side in rounds, and what it reports comes from those calls.  No timing is
asserted here, only the bookkeeping: call counts, rounds, ratios and agreement."""

from __future__ import annotations

import bench
import bench_kernel
import bench_timing


def test_interleaved_rounds_call_every_implementation_in_every_round():
    calls = []

    def fn(name, value):
        def f():
            calls.append(name)
            return value
        return f

    fns = {"a": fn("a", 1), "b": fn("b", 2), "c": fn("c", 3)}
    times, outs, rounds = bench_timing.time_interleaved(fns, min_rounds=3, max_rounds=4, budget_s=0.0)
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

    times, _, rounds = bench_timing.time_interleaved(fns, min_rounds=1, max_rounds=5, budget_s=1e9)
    assert len(rounds) == 5  # the budget is never reached: stops at max_rounds


def test_measure_config_reports_the_side_by_side_ratios():
    args = bench.parse_args(["--quick", "--min-repeats", "2", "--repeats", "4"])
    args.time_budget = args.numpy_seconds = 0.0
    rec = bench_kernel.measure_config(8, 64, 8, args)
    assert rec["agree"] and rec["max_rel_diff"] <= bench_kernel.TOLERANCE
    assert rec["rounds"] >= 2
    for name in ("kernel", "naive_vmap", "numpy"):
        assert rec[name]["repeats"] >= rec["rounds"]
        assert rec[name]["evals_per_s"] > 0
    for key in ("kernel_vs_numpy", "kernel_vs_naive_vmap"):
        lo, med, hi = rec["ratio_range"][key]
        assert 0 < lo <= med <= hi and rec[key] == med  # the ratio: the median of the rounds' ratios
    assert "rounds:" not in bench_kernel.round_ranges({})
    assert f"over {rec['rounds']} rounds" in bench_kernel.round_ranges(rec)


def test_round_ratios_are_per_round_throughput_ratios():
    # distances per call: kernel 100, numpy 10; median call times of three rounds
    rounds = [{"kernel": 1.0, "numpy": 10.0}, {"kernel": 2.0, "numpy": 10.0}, {"kernel": 1.0, "numpy": 40.0}]
    counts = {"kernel": 100, "numpy": 10}
    # kernel 100 / s against numpy 1 / s: 100; then 50; then 400
    assert bench_timing.round_ratios(rounds, counts, "kernel", "numpy") == [50.0, 100.0, 400.0]
    assert bench_kernel.round_ranges({"rounds": 3, "ratio_range": {"kernel_vs_numpy": [50.0, 100.0, 400.0],
                                                            "kernel_vs_naive_vmap": [1.0, 2.0, 3.0]}}) == \
        " (over 3 rounds: numpy 50-400x, naive 1-3x)"


def test_fast_implementations_are_called_several_times_per_round(monkeypatch):
    """Calls per round follow the first calls' times: a fake clock that each call advances."""
    now = [0.0]
    monkeypatch.setattr(bench_timing.time, "perf_counter", lambda: now[0])

    def takes(seconds):
        def f():
            now[0] += seconds
            return seconds
        return f

    fns = {"fast": takes(1 / 64), "mid": takes(1 / 16), "slow": takes(1 / 4)}  # exact in binary
    times, _, rounds = bench_timing.time_interleaved(fns, min_rounds=2, max_rounds=40, budget_s=0.0)
    assert len(rounds) == 2
    assert [len(times[n]) for n in ("fast", "mid", "slow")] == [2 * 16, 2 * 4, 2 * 1]  # 1/4 over 1/64, over 1/16
    assert rounds[0] == {"fast": 1 / 64, "mid": 1 / 16, "slow": 1 / 4}
    times, _, _ = bench_timing.time_interleaved(fns, min_rounds=4, max_rounds=8, budget_s=0.0)
    assert len(times["fast"]) == 4 * 2  # capped at max_rounds // min_rounds calls per round
