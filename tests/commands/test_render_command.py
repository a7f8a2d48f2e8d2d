"""``jaxpose render`` (``jaxpose/commands/render.py``): the image, its background and truth, a stored pose."""

from __future__ import annotations

import argparse
import json

import pytest

from jaxpose.errors import JaxposeError


def _cli(argv):
    from jaxpose.commands import eval as eval_cmd
    from jaxpose.commands import render as render_cmd

    parser = argparse.ArgumentParser(prog="jaxpose")
    sub = parser.add_subparsers()
    render_cmd.register(sub)
    eval_cmd.register(sub)
    args = parser.parse_args(argv)
    return args.func(args)


def test_render_command(tmp_path, capsys):
    out, truth, bg = tmp_path / "d.png", tmp_path / "t.json", tmp_path / "b.png"
    rc = _cli(["render", "--skeleton", "arm7", "--seed", "2", "--size", "160x120", "--floor", "--clutter", "2",
               "--out", str(out), "--truth", str(truth), "--background-out", str(bg)])
    assert rc == 0 and out.exists() and bg.exists()
    data = json.loads(truth.read_text())
    assert data["skeleton"] == {"name": "arm7", "file": "arm7"} and len(data["links"]) == 7
    assert data["camera"]["intrinsics"]["width"] == 160
    # re-render the stored pose without noise from another side
    rc = _cli(["render", "--skeleton", "arm7", "--pose", str(truth), "--size", "160x120", "--no-noise",
               "--azimuth", "90", "--out", str(tmp_path / "d2.png")])
    assert rc == 0
    with pytest.raises(JaxposeError, match="background"):
        _cli(["render", "--skeleton", "arm7", "--out", str(tmp_path / "x.png"), "--background-out", str(bg)])
    with pytest.raises(JaxposeError):
        _cli(["render", "--skeleton", "arm7", "--size", "1x", "--out", str(tmp_path / "x.png")])
