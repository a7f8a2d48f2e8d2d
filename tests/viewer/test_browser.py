"""``jaxpose view`` in a real browser: a headless Chromium loads the viewer of a fitted
demo result; the test reads back what the page received (the scene's node list, decoded
from the page's own WebSocket frames through the DevTools protocol) and what it drew
(pictures from the page's WebGL canvas, checked against the scene projected in NumPy).

Slow-marked (about a minute on two busy cores: a small fit, Chromium's start, WebGL in
software) and skipped without Chromium or Chrome; it runs with ``pytest -m slow
tests/viewer``.  docs/viewer.md, "Tests".
"""

from __future__ import annotations

import base64
import json
import math
import os
import threading
import time
import urllib.request

import numpy as np
import pytest

import jaxpose.cli as cli
from jaxpose.errors import ConfigError
from jaxpose.viewer.scene import load_view, node_names, orbit_camera

from viewer_fixtures import BACKGROUND, DEMO, TRUTH

pytestmark = pytest.mark.slow
viser = pytest.importorskip("viser")
app = pytest.importorskip("jaxpose.viewer.app")

TINY = ["--population", "32", "--generations", "10", "--islands", "1", "--no-refine", "--turns", "0",
        "--free-space-weight", "0", "--max-points", "256"]


@pytest.fixture(scope="module")
def chromium():
    try:
        return app.find_chromium()
    except ConfigError as e:
        pytest.skip(str(e))


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A fitted demo result (a small search: the scene, not the accuracy, is under test)."""
    out = tmp_path_factory.mktemp("fit") / "result.json"
    assert cli.main(["fit", DEMO, "--skeleton", "spider", "--background", BACKGROUND, *TINY, "--quiet",
                     "--out", str(out)]) == 0
    return str(out)


class DevTools:
    """The page of a headless Chromium through the DevTools protocol: commands, and the
    WebSocket frames the page receives."""

    def __init__(self, browser: app.HeadlessBrowser):
        from websockets.sync.client import connect

        port_file = os.path.join(browser.profile, "DevToolsActivePort")
        end = time.monotonic() + 60
        while not (os.path.exists(port_file) and open(port_file).read().strip()):
            assert time.monotonic() < end and browser.process.poll() is None, "Chromium did not start"
            time.sleep(0.05)
        port = int(open(port_file).read().split()[0])
        pages = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=20))
        page = next(p for p in pages if p["type"] == "page")
        self.ws = connect(page["webSocketDebuggerUrl"], max_size=None)
        self.frames: list[bytes] = []
        self.replies: dict[int, dict] = {}
        self.next_id = 0
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self):
        try:
            for raw in self.ws:
                msg = json.loads(raw)
                if msg.get("method") == "Target.attachedToTarget":  # viser's WebSocket lives in a worker
                    self.ws.send(json.dumps({"id": 10**6 + len(self.replies), "method": "Network.enable",
                                             "sessionId": msg["params"]["sessionId"]}))
                elif msg.get("method") == "Network.webSocketFrameReceived":
                    r = msg["params"]["response"]
                    if r["opcode"] == 2:  # binary
                        self.frames.append(base64.b64decode(r["payloadData"]))
                elif "id" in msg:
                    self.replies[msg["id"]] = msg
        except Exception:  # the browser closed
            pass

    def call(self, method, **params):
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        end = time.monotonic() + 60
        while self.next_id not in self.replies:
            assert time.monotonic() < end, method
            time.sleep(0.01)
        return self.replies.pop(self.next_id).get("result", {})

    def scene_nodes(self) -> set[str]:
        """The scene nodes the page holds: created minus removed, decoded from its frames
        (viser's format: two little-endian sizes, zstd-compressed msgpack, buffers)."""
        import msgspec
        import zstandard

        nodes: set[str] = set()
        for raw in self.frames:
            size, compressed = int.from_bytes(raw[:8], "little"), int.from_bytes(raw[8:16], "little")
            inner = zstandard.ZstdDecompressor().decompress(raw[16:16 + compressed], max_output_size=size)
            for m in msgspec.msgpack.decode(inner)["messages"]:
                if m.get("type") == "RemoveSceneNodeMessage":
                    nodes.discard(m["name"])
                elif m.get("type", "").endswith("Message") and isinstance(m.get("name"), str) \
                        and "props" in m and m["name"].startswith("/"):
                    nodes.add(m["name"])
        return nodes


def _white(img, tol=8):
    return np.all(img.astype(int) >= 255 - tol, axis=-1)


def _project(points, position, wxyz, fov, width, height):
    """Pixel coordinates of points seen by viser's camera (x right, y down, z forward)."""
    from scipy.spatial.transform import Rotation

    r = Rotation.from_quat([*wxyz[1:], wxyz[0]]).as_matrix()
    cam = (np.asarray(points) - position) @ r
    f = height / 2 / math.tan(fov / 2)
    return np.stack([width / 2 + f * cam[:, 0] / cam[:, 2], height / 2 + f * cam[:, 1] / cam[:, 2]], 1)


def _coloured_at(img, uv, window=2):
    h, w = img.shape[:2]
    hits = []
    for u, v in np.round(uv).astype(int):
        patch = img[max(v - window, 0):min(v + window + 1, h), max(u - window, 0):min(u + window + 1, w)]
        hits.append(patch.size > 0 and not np.all(_white(patch)))
    return np.array(hits)


def test_the_page_holds_and_draws_the_points_and_capsules(fitted, chromium):
    view = load_view(fitted, TRUTH)
    f = view.frames[0]
    doc = json.load(open(fitted))
    viewer = app.Viewer(view, port=0)
    try:
        with app.HeadlessBrowser("about:blank", chromium) as browser:
            tools = DevTools(browser)
            tools.call("Network.enable")
            tools.call("Page.enable")
            tools.call("Target.setAutoAttach", autoAttach=True, waitForDebuggerOnStart=False, flatten=True)
            tools.call("Page.navigate", url=f"http://127.0.0.1:{viewer.server.get_port()}")
            client = app.wait_for_client(viewer.server, browser)
            W, H, fov, az, el = 640, 480, 0.8, 35.0, 25.0
            position, wxyz = orbit_camera(f, view.truth, az, el, fov)

            def picture():
                viewer.show(0)
                return app.render(viewer, client, W, H, az, el, fov)

            everything = picture()
            viewer.show_points.value = viewer.show_truth.value = viewer.show_camera.value = False
            capsules = picture()
            viewer.show_points.value, viewer.show_fit.value = True, False
            points = picture()
            viewer.show_points.value = False
            nothing = picture()
            page = base64.b64decode(tools.call("Page.captureScreenshot", format="png")["data"])
            received = tools.scene_nodes()
    finally:
        viewer.stop()

    # the page's node list: the result's links, the truth's, the points, frames and camera
    names = [link["name"] for link in doc["links"]]
    expected = {"/points", "/camera"} | {f"/fit/{n}" for n in names} | {f"/joints/{n}" for n in names} \
        | {f"/truth/{link['name']}" for link in json.load(open(TRUTH))["links"]}
    assert expected <= received and set(node_names(view)) == expected
    # the pictures are the page's: blank with everything hidden, not blank with it shown
    assert np.all(_white(nothing))
    assert everything.reshape(-1, 3).std(0).min() > 20 and (~_white(everything)).mean() > 0.02
    # every capsule is drawn where its middle projects
    mids = np.array([(link.start + link.end) / 2 for link in f.links])
    assert _coloured_at(capsules, _project(mids, position, wxyz, fov, W, H)).all()
    # the points: as many as the result used, and drawn where they project
    assert len(f.points) == doc["input"]["points_used"] == len(doc["points"])
    on = _coloured_at(points, _project(f.points, position, wxyz, fov, W, H), window=1)
    assert on.mean() > 0.95, on.mean()
    # nothing else: pixels far from every projected point stay white in the points' picture
    import imageio.v3 as iio

    shot = iio.imread(page)
    assert shot.ndim == 3 and shot[..., :3].reshape(-1, 3).std(0).min() > 10  # the page itself: panel and canvas


def test_screenshot_writes_a_picture_of_the_fit(fitted, chromium, tmp_path, capsys):
    import imageio.v3 as iio

    out = tmp_path / "shot.png"
    assert cli.main(["view", fitted, TRUTH, "--screenshot", str(out), "--size", "480x360", "--joints"]) == 0
    assert capsys.readouterr().out == f"{fitted}: {out} (480x360)\n"
    img = iio.imread(out)
    assert img.shape == (360, 480, 3)
    coloured = ~_white(img)
    assert 0.02 < coloured.mean() < 0.9  # the scene, on a white background
    assert not [p for p in os.listdir(tmp_path) if p != "shot.png"]  # no temporary file left
