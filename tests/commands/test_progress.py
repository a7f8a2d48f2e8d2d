"""The progress bar of ``jaxpose fit`` (``jaxpose/commands/progress.py``).

Documented (ProgressBar docstring, README "Command line"): ``generation/total, best
cost, evaluations per second`` on one line of stderr; nothing when stderr is not a
terminal or with ``--quiet``.  The line is ``\\r[###---] gen G/T  best C  E evals/s``
rewritten in place, ended by one newline at close.

The clock is replaced by a fake one, so the evaluations-per-second figure is exact
(no assertion depends on real time).
"""

from __future__ import annotations

import io
import json
import re
import sys
import types

import pytest

import jaxpose.commands.progress as progress
from jaxpose.cli import main
from jaxpose.commands.progress import ProgressBar

LINE = re.compile(r"^\r\[(#*)(-*)\] gen (\d+)/(\d+)  best (-?[0-9]+\.[0-9]{5})  ([0-9,]+) evals/s $")

# the same small fit as tests/commands/test_cli.py (one compilation per session for both files)
FIT = ["--skeleton", "spider", "--population", "32", "--generations", "10", "--islands", "1",
       "--no-refine", "--turns", "0", "--limb-sweep", "0", "--pivot-sweep", "0", "--free-space-weight", "0",
       "--max-points", "256"]


class TTY(io.StringIO):
    def isatty(self):
        return True


class NotTTY(io.StringIO):
    def isatty(self):
        return False


class NoIsatty:
    """A stream without ``isatty`` at all."""

    def __init__(self):
        self.written = []

    def write(self, s):
        self.written.append(s)

    def flush(self):
        pass


@pytest.fixture
def clock(monkeypatch):
    """A fake ``time.perf_counter`` for the progress module: returns ``clock.t``, then
    advances it by ``clock.step`` seconds (0 unless a test sets it)."""
    c = types.SimpleNamespace(t=100.0, step=0.0)

    def perf_counter():
        t = c.t
        c.t += c.step
        return t

    monkeypatch.setattr(progress, "time", types.SimpleNamespace(perf_counter=perf_counter))
    return c


def _lines(text):
    assert text.startswith("\r")
    return ["\r" + part for part in text.split("\r")[1:]]


def test_bar_line_content(clock):
    s = TTY()
    bar = ProgressBar(40, stream=s, width=20)
    clock.t += 2.0
    bar.update(10, 0.123456, 5000)
    clock.t += 2.0
    bar.update(40, 0.0421, 24000)
    bar.close()
    text = s.getvalue()
    assert text.endswith("\n") and text.count("\n") == 1  # one line, ended once
    first, last = _lines(text[:-1])
    m = LINE.match(first)
    assert m, first
    hashes, dashes, gen, total, best, rate = m.groups()
    assert (len(hashes), len(dashes)) == (5, 15)  # 10/40 of 20 cells
    assert (int(gen), int(total)) == (10, 40)
    assert float(best) == pytest.approx(0.12346, abs=1e-12)
    assert int(rate.replace(",", "")) == 5000 // 2  # 5000 evaluations in 2 s
    m = LINE.match(last)
    assert m, last
    hashes, dashes, gen, total, best, rate = m.groups()
    assert (len(hashes), len(dashes), int(gen), int(total)) == (20, 0, 40, 40)
    assert best == "0.04210"
    assert rate == "6,000"  # thousands separator; 24000 evaluations in 4 s


def test_bar_fill_follows_the_generation(clock):
    s = TTY()
    bar = ProgressBar(7, stream=s, width=30)
    for g in range(0, 10):  # past the total the bar stays full
        clock.t += 1.0
        bar.update(g, 1.0, 10 * g)
    lines = _lines(s.getvalue())
    assert len(lines) == 10
    for g, line in enumerate(lines):
        m = LINE.match(line)
        assert m, line
        filled = int(min(g / 7, 1.0) * 30)
        assert (len(m.group(1)), len(m.group(2))) == (filled, 30 - filled)
        assert (int(m.group(3)), int(m.group(4))) == (g, 7)
        assert int(m.group(6)) == round(10 * g / (g + 1))


@pytest.mark.parametrize("make", [NotTTY, NoIsatty])
def test_silent_when_not_a_terminal(make, clock):
    s = make()
    bar = ProgressBar(10, stream=s)
    bar.update(5, 0.5, 100)
    bar.close()
    assert (s.getvalue() if isinstance(s, io.StringIO) else "".join(s.written)) == ""
    assert not bar.enabled


def test_silent_when_quiet_even_on_a_terminal(clock):
    s = TTY()
    bar = ProgressBar(10, quiet=True, stream=s)
    bar.update(5, 0.5, 100)
    bar.close()
    assert s.getvalue() == ""


def test_close_without_update_writes_nothing():
    s = TTY()
    ProgressBar(10, stream=s).close()
    assert s.getvalue() == ""


def test_default_stream_is_stderr(monkeypatch, clock):
    fake = TTY()
    monkeypatch.setattr(sys, "stderr", fake)
    bar = ProgressBar(4)
    clock.t += 1.0
    bar.update(2, 0.25, 8)
    assert LINE.match(fake.getvalue())


# --------------------------------------------------------------------------- through the command line




def test_quiet_fit_prints_nothing(scene, capsys, monkeypatch):
    """``--quiet``: neither the bar (even on a terminal) nor the summary line."""
    capsys.readouterr()
    fake = TTY()
    monkeypatch.setattr(sys, "stderr", fake)
    out = scene / "quiet.json"
    rc = main(["fit", str(scene / "depth.png"), "--intrinsics", str(scene / "truth.json"), "--seed", "7",
               "--out", str(out), "--quiet"] + FIT)
    stdout, stderr = capsys.readouterr()
    assert rc == 0 and out.exists()
    assert fake.getvalue() == "" and stderr == "" and stdout == ""


def test_fit_on_a_terminal_shows_the_bar(scene, capsys, monkeypatch, clock):
    clock.step = 1.0  # one second between the bar's creation and each update
    fake = TTY()
    monkeypatch.setattr(sys, "stderr", fake)
    out = scene / "tty.json"
    rc = main(["fit", str(scene / "depth.png"), "--intrinsics", str(scene / "truth.json"), "--seed", "7",
               "--out", str(out)] + FIT)
    assert rc == 0
    doc = json.loads(out.read_text())
    text = fake.getvalue()
    assert text.endswith("\n")
    lines = _lines(text[:-1])
    m = LINE.match(lines[-1])
    assert m, lines[-1]
    hashes, dashes, gen, total, best, rate = m.groups()
    # the default portfolio's two searches of 10 generations, one after the other
    assert (int(gen), int(total)) == (20, 20) and dashes == ""
    # the best cost after the last generation, as in the result's history (no refinement)
    assert float(best) == pytest.approx(doc["cost_history"][-1], abs=5e-6)
    # one update per compiled chunk, each one fake second after the previous clock reading:
    # the last rate is the evaluation count, 2 * 32 * 10 as in result.json, over len(lines) s
    evaluations = doc["evaluations"]["objective"] + doc["evaluations"]["gradient"]
    assert evaluations == 2 * 32 * 10  # two searches of 10 generations of 32, the first the initial population
    assert int(rate.replace(",", "")) == round(evaluations / len(lines))
    for line in lines[:-1]:
        assert LINE.match(line)
    stdout, _ = capsys.readouterr()
    assert stdout.startswith("spider: cost ")


def test_fit_not_on_a_terminal_writes_nothing_to_stderr(scene, capsys):
    capsys.readouterr()
    out = scene / "pipe.json"
    rc = main(["fit", str(scene / "depth.png"), "--intrinsics", str(scene / "truth.json"), "--seed", "7",
               "--out", str(out)] + FIT)
    stdout, stderr = capsys.readouterr()
    assert rc == 0 and stderr == "" and stdout.startswith("spider: cost ")
