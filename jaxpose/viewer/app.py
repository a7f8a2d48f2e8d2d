"""The web viewer: a :class:`~jaxpose.viewer.scene.View` drawn with viser (optional extra ``view``).

:class:`Viewer` puts the scene on a viser server and adds the panel: what to show,
how to colour the points, and for a sequence the frame slider, play/pause and each
frame's cost and mode.  :func:`screenshot` renders one picture through a headless
Chromium, without a window.  docs/viewer.md.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import shutil
import subprocess
import tempfile
import threading
import time

import numpy as np

from ..errors import ConfigError
from .scene import (DISTANCE_RANGE, View, capsule_mesh, frame_caption, frustum, joint_frames, link_colours,
                    orbit_camera, point_colours)

INSTALL = "the viewer needs viser: pip install 'jaxpose[view]'"
TRUTH_COLOUR = (230, 30, 30)
FIT_OPACITY = 0.6  # with a truth: the fitted capsules let its axes show through
BACKGROUND = (255, 255, 255)
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")


def quiet():
    """Hold what viser prints to stdout (its address box, "Server stopped")."""
    return contextlib.redirect_stdout(io.StringIO())


def require_viser():
    """The viser module; :class:`ConfigError` with the line that installs it when it is missing."""
    try:
        import viser
    except ImportError:
        raise ConfigError(INSTALL) from None
    return viser


class Viewer:
    """A :class:`View` on a viser server (``host``, ``port``; port 0: a free one)."""

    def __init__(self, view: View, host: str = "127.0.0.1", port: int = 8080, point_size: float = 0.004):
        viser = require_viser()
        # a browser that opens a connection and drops it before the handshake is not an error
        logging.getLogger("websockets").setLevel(logging.CRITICAL)
        self.view = view
        with quiet():  # viser prints a box with its address; the command prints one line
            self.server = viser.ViserServer(host=host, port=port, label=f"jaxpose: {view.title}", verbose=False)
        self.server.scene.set_up_direction("-y")  # the sensor's image: y down
        self.index = 0
        self.playing = False
        self._stopped = threading.Event()
        self._lock = threading.RLock()
        self.nodes: dict[str, object] = {}
        self._gui(point_size)
        self.show(0)
        self._player = None
        if view.is_sequence:
            self._player = threading.Thread(target=self._play_loop, daemon=True)
            self._player.start()

    # ------------------------------------------------------------------ panel

    def _gui(self, point_size: float) -> None:
        gui = self.server.gui
        v = self.view
        self.caption = gui.add_markdown(frame_caption(v, 0))
        with gui.add_folder("Show"):
            self.show_points = gui.add_checkbox("Points", True)
            self.show_fit = gui.add_checkbox("Fitted capsules", True)
            self.show_truth = gui.add_checkbox("Truth", True, disabled=v.truth is None)
            self.show_joints = gui.add_checkbox("Joint frames", False)
            self.show_names = gui.add_checkbox("Link names", False)
            self.show_camera = gui.add_checkbox("Camera", True)
        with gui.add_folder("Points"):
            self.colour_by = gui.add_dropdown("Colour by", ("depth", "distance to model"), initial_value="depth")
            self.point_size = gui.add_slider("Size (m)", 0.001, 0.03, 0.001, point_size)
            gui.add_markdown(f"distance: 0 (dark blue) to {DISTANCE_RANGE * 100:g} cm or more (yellow)")
        self.picked = gui.add_markdown("Click a capsule to name it.")
        if v.is_sequence:
            with gui.add_folder("Sequence"):
                self.slider = gui.add_slider("Frame", 0, len(v.frames) - 1, 1, 0)
                self.play = gui.add_button("Play")
                self.fps = gui.add_number("Frames per second", float(v.fps or 10.0), min=0.1, max=120.0, step=0.1)

            @self.slider.on_update
            def _(_):
                if int(self.slider.value) != self.index:
                    self.show(int(self.slider.value))

            @self.play.on_click
            def _(_):
                self.playing = not self.playing
                self.play.label = "Pause" if self.playing else "Play"

        for box in (self.show_points, self.show_fit, self.show_truth, self.show_joints, self.show_names,
                    self.show_camera, self.colour_by, self.point_size):
            box.on_update(lambda _: self.show(self.index))

    def _play_loop(self) -> None:
        while not self._stopped.wait(1.0 / max(float(self.fps.value), 0.1)):
            if self.playing:
                nxt = (self.index + 1) % len(self.view.frames)
                self.slider.value = nxt
                self.show(nxt)

    # ------------------------------------------------------------------ scene

    def show(self, index: int) -> None:
        """Draw frame ``index`` (every node of the previous frame is replaced or removed)."""
        with self._lock, self.server.atomic():
            self.index = index
            scene, v = self.server.scene, self.view
            f = v.frames[index]
            self.caption.content = frame_caption(v, index)
            drawn: dict[str, object] = {}
            if f.points is not None:
                mode = "depth" if self.colour_by.value == "depth" else "distance"
                drawn["/points"] = scene.add_point_cloud(
                    "/points", f.points.astype(np.float32), point_colours(f.points, mode, f.links),
                    point_size=float(self.point_size.value), point_shape="circle",
                    visible=bool(self.show_points.value))
            colours = link_colours(len(f.links))
            for link, colour in zip(f.links, colours):
                verts, faces = capsule_mesh(link.start, link.end, link.radius)
                name = f"/fit/{link.name}"
                drawn[name] = h = scene.add_mesh_simple(name, verts, faces, color=tuple(int(c) for c in colour),
                                                        opacity=FIT_OPACITY if v.truth else None,
                                                        visible=bool(self.show_fit.value))
                h.on_click(self._namer(link, "fitted"))
                label = f"/names/{link.name}"
                drawn[label] = scene.add_label(label, link.name, position=(link.start + link.end) / 2,
                                               visible=bool(self.show_names.value))
            for link in v.truth or []:  # the truth's capsule axes, seen through the fitted capsules
                name = f"/truth/{link.name}"
                drawn[name] = scene.add_line_segments(
                    name, np.array([[link.start, link.end]], np.float32), TRUTH_COLOUR, thickness=4.0,
                    thickness_units="screen", visible=bool(self.show_truth.value))
            size = max([float(np.linalg.norm(link.end - link.start)) for link in f.links] + [0.02]) * 0.4
            for link, (pos, wxyz) in zip(f.links, joint_frames(f.links)):
                name = f"/joints/{link.name}"
                drawn[name] = scene.add_frame(name, axes_length=size, axes_radius=size * 0.05, position=pos,
                                              wxyz=wxyz, visible=bool(self.show_joints.value))
            fov, aspect = frustum(f.intrinsics)
            drawn["/camera"] = scene.add_camera_frustum("/camera", fov, aspect, scale=0.15, thickness=0.004,
                                                        visible=bool(self.show_camera.value))
            for name, handle in self.nodes.items():
                if name not in drawn:
                    handle.remove()
            self.nodes = drawn

    def _namer(self, link, what: str):
        def named(_event):
            length = float(np.linalg.norm(link.end - link.start))
            self.picked.content = (f"**{link.name}** ({what}; parent {link.parent or 'none'}): "
                                   f"length {length * 100:.1f} cm, radius {link.radius * 100:.1f} cm")
        return named

    def address(self) -> str:
        host = self.server.get_host()
        shown = "localhost" if host in ("0.0.0.0", "::", "127.0.0.1") else host
        return f"http://{shown}:{self.server.get_port()}"

    def stop(self) -> None:
        self._stopped.set()
        if self._player is not None:
            self._player.join()
        with quiet():
            self.server.stop()


# --------------------------------------------------------------------------- screenshots


def find_chromium() -> str:
    """A Chromium or Chrome executable: ``$JAXPOSE_CHROMIUM``, else the first on ``PATH``;
    :class:`ConfigError` when there is none."""
    env = os.environ.get("JAXPOSE_CHROMIUM")
    if env:
        if os.path.isfile(env) and os.access(env, os.X_OK):
            return env
        raise ConfigError(f"JAXPOSE_CHROMIUM {env}: not an executable file (--screenshot needs Chromium or Chrome)")
    for name in CHROMIUM_NAMES:
        found = shutil.which(name)
        if found:
            return found
    raise ConfigError("--screenshot needs Chromium or Chrome (none on PATH; install one, or set JAXPOSE_CHROMIUM "
                      "to its executable)")


CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",  # WebGL in software: no GPU, no display
    "--remote-debugging-port=0",  # keeps a headless browser open on the page
)


class HeadlessBrowser:
    """A headless Chromium showing ``url`` until closed (a context manager); its profile is
    a fresh temporary folder, removed on close."""

    def __init__(self, url: str, executable: str, width: int = 1280, height: int = 960):
        self.profile = tempfile.mkdtemp(prefix="jaxpose-chromium-")
        cmd = [executable, *CHROMIUM_FLAGS, f"--user-data-dir={self.profile}", f"--window-size={width},{height}", url]
        self.process = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        shutil.rmtree(self.profile, ignore_errors=True)


def wait_for_client(server, browser: HeadlessBrowser, timeout: float = 60.0):
    """The first client to connect to ``server``; :class:`ConfigError` when the browser ends
    or none connects in time."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        clients = server.get_clients()
        if clients:
            return next(iter(clients.values()))
        if browser.process.poll() is not None:
            raise ConfigError(f"--screenshot: the browser ended (status {browser.process.returncode}) "
                              "before it showed the scene")
        time.sleep(0.05)
    raise ConfigError(f"--screenshot: the browser did not show the scene within {timeout:g} s")


def render(viewer: Viewer, client, width: int, height: int, azimuth: float, elevation: float,
           fov: float = 0.8, timeout: float = 60.0) -> np.ndarray:
    """One ``(height, width, 3)`` uint8 picture of the viewer's current frame, from
    :func:`~jaxpose.viewer.scene.orbit_camera`, on a white background."""
    f = viewer.view.frames[viewer.index]
    position, wxyz = orbit_camera(f, viewer.view.truth, azimuth, elevation, fov)
    time.sleep(0.5)  # let the page take in the scene's messages
    rgba = client.get_render(height, width, wxyz=wxyz, position=position, fov=fov, transport_format="png",
                             timeout=timeout)
    rgba = np.asarray(rgba)
    if rgba.shape[-1] == 3:
        return rgba.astype(np.uint8)
    alpha = rgba[..., 3:4].astype(np.float64) / 255.0
    out = rgba[..., :3] * alpha + np.asarray(BACKGROUND, np.float64) * (1 - alpha)
    return np.round(out).astype(np.uint8)


def screenshot(view: View, path: str, width: int = 960, height: int = 720, azimuth: float = 35.0,
               elevation: float = 25.0, frame: int = 0, show_joints: bool = False,
               chromium: str | None = None) -> np.ndarray:
    """Render frame ``frame`` of ``view`` to the PNG ``path`` through a headless Chromium
    (no window, no display needed) and return the picture."""
    from ..io.atomic import atomic_write

    exe = chromium or find_chromium()
    viewer = Viewer(view, host="127.0.0.1", port=0)
    try:
        viewer.show_joints.value = show_joints
        viewer.show(frame)
        with HeadlessBrowser(f"http://127.0.0.1:{viewer.server.get_port()}", exe,
                             width=max(1280, width), height=max(960, height)) as browser:
            client = wait_for_client(viewer.server, browser)
            picture = render(viewer, client, width, height, azimuth, elevation)
    finally:
        viewer.stop()
    import imageio.v3 as iio

    atomic_write(path, lambda fh: fh.write(iio.imwrite("<bytes>", picture, extension=".png")), binary=True)
    return picture


def serve(view: View, host: str, port: int, on_ready=None) -> None:
    """Serve ``view`` until Ctrl-C; ``on_ready(address)`` once the server listens."""
    viewer = Viewer(view, host=host, port=port)
    try:
        if on_ready:
            on_ready(viewer.address())
        while True:
            time.sleep(3600)
    finally:
        viewer.stop()


__all__ = ["Viewer", "require_viser", "screenshot", "serve", "find_chromium", "HeadlessBrowser", "render",
           "wait_for_client", "INSTALL"]
