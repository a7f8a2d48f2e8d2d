"""experiments/common.py's check of a fit's evaluation counts against its plan: with
adaptive restarts a fit may stop after any whole round, so each round's count is
expected; otherwise only the full plan."""

import dataclasses

import common
import pytest

from jaxpose.search import FitConfig

BASE = FitConfig(generations=10, limb_sweep=0, pivot_sweep=0, restarts=3)


@pytest.mark.parametrize("apart, rounds, warns", [(0.2, 1, False), (0.2, 2, False), (0.2, 3, False),
                                                  (0.0, 1, True), (0.0, 3, False)])
def test_counts_of_whole_rounds_pass_only_with_adaptive_restarts(apart, rounds, warns, capsys):
    config = dataclasses.replace(BASE, restart_apart=apart)
    plan = common.planned_evaluations(config)
    rec = {"objective_evaluations": plan["objective"] // 3 * rounds,
           "gradient_evaluations": plan["gradient"] // 3 * rounds}
    common.FitRunner(None, 0)._check_counts(rec, config, "ga", None)
    assert ("warning: ga" in capsys.readouterr().out) == warns


def test_a_count_off_the_rounds_warns(capsys):
    config = dataclasses.replace(BASE, restart_apart=0.2)
    plan = common.planned_evaluations(config)
    rec = {"objective_evaluations": plan["objective"] // 3 + 1, "gradient_evaluations": plan["gradient"] // 3}
    common.FitRunner(None, 0)._check_counts(rec, config, "ga", None)
    assert "warning: ga" in capsys.readouterr().out
