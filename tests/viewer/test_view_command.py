"""``jaxpose view``: its documented errors (docs/errors.md, rows V*), the panel and scene
it serves (a viser server, no browser), and the address it prints.  The test in a real
browser is tests/viewer/test_browser.py."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

import jaxpose.cli as cli
from jaxpose import errors
from jaxpose.io.truth import TruthError
from jaxpose.viewer.scene import load_view, node_names

from viewer_fixtures import TRUTH, demo_result, sequence, write

DOC = Path(__file__).resolve().parents[2] / "docs" / "errors.md"
viser = pytest.importorskip("viser")


def view_rows():
    rows = []
    for line in DOC.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 7 or "test_view_error" not in cells[6]:
            continue
        code = lambda c: re.findall(r"`([^`]*)`", c)  # noqa: E731
        rows.append(pytest.param(code(cells[2])[0], code(cells[3])[0], cells[4].strip("`"), int(cells[5]),
                                 id=cells[0]))
    return rows


ROWS = view_rows()


@pytest.fixture(scope="module")
def view_inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("view")
    write(d / "result.json", demo_result(max_points=100))
    shutil.copy(TRUTH, d / "truth.json")
    (d / "broken.json").write_text('{"links": [')
    write(d / "nolinks.json", {"cost": 1})
    os.makedirs(d / "empty")
    sequence(d / "seq", n=3)
    os.makedirs(d / "gap")
    write(d / "gap" / "a.json", demo_result(max_points=60))
    write(d / "gap" / "track.json", {"frames": [{"input": "frames/a.png"}, {"input": "frames/b.png"}]})
    return d


def _hide(module):
    def setup(mp):
        mp.setitem(sys.modules, module, None)  # import fails as when not installed
    return setup


SETUP = {
    "V7": [_hide("viser")],
    "V8": [lambda mp: mp.setenv("PATH", ""), lambda mp: mp.delenv("JAXPOSE_CHROMIUM", raising=False)],
}


def test_every_row_is_found():
    assert [r.id for r in ROWS] == [f"V{i}" for i in range(1, len(ROWS) + 1)] and len(ROWS) >= 13


@pytest.mark.parametrize("command,message,exception,status", ROWS)
def test_view_error(request, command, message, exception, status, view_inputs, capsys, monkeypatch):
    """The row's command ends with exactly its line and status, having started no server."""
    monkeypatch.chdir(view_inputs)
    for setup in SETUP.get(request.node.callspec.id, []):
        setup(monkeypatch)
    raised = []
    real = cli.one_line
    monkeypatch.setattr(cli, "one_line", lambda e: raised.append(type(e).__name__) or real(e))
    monkeypatch.setattr("jaxpose.viewer.app.Viewer", None)  # a server would be a failure here
    argv = shlex.split(command)
    rc = cli.main(argv[1:])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == status and len(err) == 1, err
    if message.endswith("..."):
        assert err[0].startswith(message[:-3]), err[0]
    else:
        assert err[0] == message
    assert raised == [exception]
    assert issubclass(getattr(errors, exception, TruthError), errors.JaxposeError)
    assert not os.path.exists("shot.png")


# --------------------------------------------------------------------------- the served scene


def test_the_server_holds_the_scene_and_the_panel_switches_it(tmp_path):
    from jaxpose.viewer.app import Viewer

    view = load_view(write(tmp_path / "r.json", demo_result(max_points=300)), TRUTH)
    v = Viewer(view, port=0)
    try:
        drawn = [n for n in v.nodes if not n.startswith("/names/")]
        assert sorted(drawn) == sorted(node_names(view))
        assert len(v.nodes["/points"].points) == 300
        assert v.nodes["/fit/leg0_upper"].visible and not v.nodes["/joints/leg0_upper"].visible
        v.show_joints.value = True
        v.show_points.value = False
        v.show(0)
        assert v.nodes["/joints/leg0_upper"].visible and not v.nodes["/points"].visible
        v.colour_by.value = "distance to model"
        v.show(0)
        assert v.address().startswith("http://localhost:")
    finally:
        v.stop()


def test_a_sequence_has_a_slider_and_shows_each_frames_links_and_mode(tmp_path):
    from jaxpose.viewer.app import Viewer

    docs = sequence(tmp_path / "seq", n=3)
    view = load_view(str(tmp_path / "seq"))
    v = Viewer(view, port=0)
    try:
        assert (v.slider.min, v.slider.max) == (0, 2) and v.fps.value == 12.5
        for i in (2, 1):
            v.slider.value = i
            v.show(i)
            mesh = v.nodes["/fit/leg0_upper"]
            assert abs(float(mesh.vertices[:, 0].mean()) - docs[i]["links"][0]["start"][0]) < 0.2
            assert v.caption.content.startswith(f"frame {i}, {docs[i]['tracking']['mode']}, cost")
        v.playing = True  # what the Play button sets
        end = time.monotonic() + 10
        while v.index == 1 and time.monotonic() < end:
            time.sleep(0.02)
        assert v.index == 2 and int(v.slider.value) == 2  # the next frame, at 12.5 frames per second
    finally:
        v.stop()


def test_without_viser_the_command_says_how_to_install_it(view_inputs, capsys, monkeypatch):
    monkeypatch.chdir(view_inputs)
    monkeypatch.setitem(sys.modules, "viser", None)
    assert cli.main(["view", "result.json"]) == 2
    assert capsys.readouterr().err == "jaxpose: error: the viewer needs viser: pip install 'jaxpose[view]'\n"


def test_the_command_prints_its_address_serves_the_page_and_ends_on_ctrl_c(view_inputs):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    p = subprocess.Popen([sys.executable, "-m", "jaxpose.cli", "view", "result.json", "truth.json", "--port", "0"],
                         cwd=view_inputs, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                         # a child inherits an ignored SIGINT (Python then never raises KeyboardInterrupt): reset it
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        line = p.stdout.readline()
        m = re.fullmatch(r"jaxpose view: result.json \(8 links\) at (http://localhost:\d+) \(Ctrl-C ends it\)\n",
                         line)
        assert m, (line, p.stderr.read() if p.poll() is not None else "")
        page = urllib.request.urlopen(m.group(1), timeout=20).read().decode()
        assert "<html" in page.lower()
    finally:
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=90)  # generous: on a loaded 2-core machine shutdown took over 20 s
    assert p.returncode == 0 and err == "" and out == "", (out, err)


def test_view_is_listed_in_the_help(capsys):
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["--help"])
    assert re.search(r"\n\s+view\s+look at a fit", capsys.readouterr().out)
