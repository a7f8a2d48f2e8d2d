"""The experiments' run store: finished fits are kept, a rerun skips them, and an
interrupted run loses only the fit in progress (experiments/common.py)."""

from __future__ import annotations

import json
import os

import common
import pytest

from jaxpose.search import FitConfig


@pytest.fixture
def fake_fits(monkeypatch):
    """Replace the (expensive) fit and image loading by a counter; optionally interrupt."""
    calls = []
    state = {"interrupt_at": None}

    def fit_image(ds, img, config, seed):
        calls.append(img.name)
        if state["interrupt_at"] is not None and len(calls) == state["interrupt_at"]:
            raise KeyboardInterrupt
        return {"image": img.name, "seed": seed, "symmetric": {"pcp": 1.0, "mpjpe_mm": 1.0},
                "strict": {"pcp": 1.0}, "objective_evaluations": -1, "gradient_evaluations": -1,
                "wall_seconds": 0.5}

    monkeypatch.setattr(common, "fit_image", fit_image)
    monkeypatch.setattr(common, "load_image", lambda ds, e: common.Image(ds.model, e["name"], e, *([None] * 4)))
    monkeypatch.setattr(common, "log", lambda msg="": None)
    return calls, state


def _dataset():
    index = {"images": [{"name": f"img{i}"} for i in range(3)]}
    return common.Dataset("spider", "nowhere", None, index, "0123456789ab")


def _run_all(store, ds, config):
    runner = common.FitRunner(store, len(ds.entries))
    return runner, [runner.run(ds, e, "ga", config, 0) for e in ds.entries]


def test_rerun_skips_stored_fits(tmp_path, fake_fits, monkeypatch):
    calls, _ = fake_fits
    monkeypatch.setattr(common, "depth_options_record", lambda ds: {})
    store, ds, config = common.RunStore(str(tmp_path)), _dataset(), FitConfig(
        population=8, generations=2, limb_sweep=0, pivot_sweep=0, turns=0)
    runner, recs = _run_all(store, ds, config)
    assert calls == ["img0", "img0", "img1", "img2"]  # one warm-up, then every image once
    assert (runner.ran, runner.skipped) == (3, 0)
    files = sorted(os.listdir(tmp_path))
    assert len(files) == 4 and sum(f.startswith("warmup__") for f in files) == 1
    assert all(json.load(open(tmp_path / f))["image"].startswith("img") for f in files)
    # a second process: nothing runs again, the stored records come back unchanged
    calls.clear()
    runner2, recs2 = _run_all(common.RunStore(str(tmp_path)), ds, config)
    assert calls == [] and (runner2.ran, runner2.skipped) == (0, 3)
    assert [r["key"] for r in recs2] == [r["key"] for r in recs]
    # another config is another set of runs
    _run_all(common.RunStore(str(tmp_path)), ds,
             FitConfig(population=8, generations=3, limb_sweep=0, pivot_sweep=0, turns=0))
    assert len(calls) == 4


def test_interrupted_run_keeps_finished_fits_and_resumes(tmp_path, fake_fits, monkeypatch):
    calls, state = fake_fits
    monkeypatch.setattr(common, "depth_options_record", lambda ds: {})
    store, ds, config = common.RunStore(str(tmp_path)), _dataset(), FitConfig(
        population=8, generations=2, limb_sweep=0, pivot_sweep=0, turns=0)
    state["interrupt_at"] = 3  # warm-up, img0, then Ctrl-C during img1
    with pytest.raises(KeyboardInterrupt):
        _run_all(store, ds, config)
    files = sorted(os.listdir(tmp_path))
    assert len(files) == 2 and not [f for f in files if not f.endswith(".json")]  # no partial or temporary file
    state["interrupt_at"] = None
    calls.clear()
    runner, _ = _run_all(common.RunStore(str(tmp_path)), ds, config)
    assert calls == ["img1", "img1", "img2"]  # a fresh process warms up again, then only the missing fits
    assert (runner.ran, runner.skipped) == (2, 1)


def test_unreadable_stored_record_is_run_again(tmp_path):
    store = common.RunStore(str(tmp_path))
    store.put("k", {"a": 1})
    assert store.get("k") == {"a": 1}
    (tmp_path / "k.json").write_text("{not json")
    assert store.get("k") is None


def test_sweep_islands_flag_sets_the_configs_islands():
    import sweep_population as S

    args = S.parse_args(["--islands", "1", "--quick"])
    assert args.islands == 1
    cfg = S.evals_config("ga", 16, args.budget, args.islands)
    assert cfg.islands == 1 and cfg.population == 16 and cfg.generations == args.budget // 16
    assert S.parse_args(["--quick"]).islands == FitConfig().islands  # the default: FitConfig's
    with pytest.raises(SystemExit):
        S.parse_args(["--islands", "0"])


def test_seed_stats_leave_out_records_that_could_not_be_scored():
    recs = [{"seed": 0, "v": 0.5}, {"seed": 0, "v": None}, {"seed": 1, "v": 1.0}, {"seed": 1, "v": 0.0}]
    st = common.seed_stats(recs, lambda r: r["v"])
    assert st["per_seed"] == {0: 0.5, 1: 0.5}
    assert st["mean"] == pytest.approx(0.5) and st["std"] == pytest.approx(0.0)
    assert common.seed_stats([{"seed": 0, "v": None}], lambda r: r["v"]) == {"mean": None, "std": None, "per_seed": {}}
    assert common.mean_scored([None, 0.25, 0.75]) == pytest.approx(0.5) and common.mean_scored([None]) is None
