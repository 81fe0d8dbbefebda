"""An interactive 4D viewer of a trained run in the browser, served by viser on this machine.

viser draws the scene's camera controls (orbit, pan, zoom) and the GUI; every frame the browser
shows is rendered by surgsplat's own CPU renderer at the browser's camera and canvas size and
sent as the scene background. While the camera moves, frames are rendered at a lower resolution
(`moving_scale`); once it rests, the full-resolution frame follows. The viewer starts at the
first training camera; a time slider with play/pause scrubs through the clip, and a channel
selector shows any channel the model declares (`SplatModel.channel_descriptors`: the colour,
depth and normals, and those its components add, e.g. reflectance or illumination), each as its
descriptor says (`export.channel_image`), and the tool-free colour of a method that separates the
tool (its tissue-only render). A run still being trained (`surgsplat stream`) is followed: each
newer checkpoint replaces the one shown, at its latest frame.

viser's client is bundled with the Python package and served from this machine: the page needs
no internet access. Camera poses follow viser's convention, P_world = R p_camera + t with OpenCV
camera axes (x right, y down, z forward), which is surgsplat's too.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from surgsplat.data.scene import Camera
from surgsplat.errors import SurgsplatError
from surgsplat.export.channel_image import channel_image
from surgsplat.model.channels import RGB
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import SplatModel, render_frame
from surgsplat.render.rotation import quaternion_to_matrix
from surgsplat.train.run import TrainedRun

FOLLOW_SECONDS = 1.0
"""How often a viewer of a run being trained asks for a newer state of it."""
TOOL_FREE = "tool_free"
"""Channel: the colour of the tissue-only render, for methods that separate the tool."""


@dataclass
class ViewerFrame:
    """The last frame sent to a browser."""

    index: int  # frame (time) index of the clip
    channel: str
    image: np.ndarray  # uint8 RGB [H, W, 3]
    seconds: float  # time it took to render and colour-map


def viewer_channels(model: SplatModel) -> list[str]:
    """The channels the viewer offers for `model`: every channel it declares, and TOOL_FREE
    when it separates the tool."""
    names = [channel.name for channel in model.channel_descriptors()]
    return names + [TOOL_FREE] if model.separates_tool else names


def view_image(run: TrainedRun, camera: Camera, index: int, channel: str) -> np.ndarray:
    """uint8 RGB [H, W, 3] of `channel` (one of `viewer_channels`) of `run` at frame `index`
    seen by `camera`."""
    frame = run.scene.frames[index]
    background = torch.tensor(run.config.train.background, dtype=torch.float32)
    when = FrameTime(index, frame.time, tissue_only=channel == TOOL_FREE)
    out = render_frame(run.model, camera, when, background)
    shown = RGB if channel == TOOL_FREE else channel
    descriptor = next(c for c in run.model.channel_descriptors() if c.name == shown)
    return channel_image(out, descriptor, camera.K)


def matrix_to_wxyz(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a 3x3 rotation matrix."""
    w = math.sqrt(max(0.0, 1.0 + rotation[0, 0] + rotation[1, 1] + rotation[2, 2])) / 2.0
    x = math.copysign(math.sqrt(max(0.0, 1.0 + rotation[0, 0] - rotation[1, 1] - rotation[2, 2])) / 2.0,
                      rotation[2, 1] - rotation[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - rotation[0, 0] + rotation[1, 1] - rotation[2, 2])) / 2.0,
                      rotation[0, 2] - rotation[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - rotation[0, 0] - rotation[1, 1] + rotation[2, 2])) / 2.0,
                      rotation[1, 0] - rotation[0, 1])
    return np.array([w, x, y, z])


def check_can_serve(host: str, port: int) -> None:
    """SurgsplatError naming `host:port` unless a server can listen there now (every address
    `host` resolves to, bound as the viewer's server binds them). viser would otherwise move on
    to the next free port when `port` is taken, and wait forever when `host` cannot be bound."""
    try:
        addresses = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM,
                                       flags=socket.AI_PASSIVE)
        for family, kind, protocol, _, address in addresses:
            with socket.socket(family, kind, protocol) as probe:
                probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                if family == socket.AF_INET6:
                    probe.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
                probe.bind(address)
    except OSError as err:  # socket.gaierror too: a host name that does not resolve
        raise SurgsplatError(f"--host {host} --port {port}: cannot serve there "
                             f"({err.strerror or err}); choose another --port or --host") from None


def http_url(host: str, port: int) -> str:
    """The address of a web server on `host`:`port` as a browser takes it: an IPv6 address in
    brackets (http://[::1]:8080), any other host as it is."""
    return f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"


class RunViewer:
    """A viser server showing `run` on `host`:`port` (SurgsplatError when it cannot listen
    there; see check_can_serve); see the module docstring."""

    def __init__(self, run: TrainedRun, host: str = "127.0.0.1", port: int = 8080,
                 height: int | None = None, moving_scale: float = 0.5, fps: float = 10.0,
                 follow: Callable[[], TrainedRun | None] | None = None):
        """follow: for a run still being trained (a stream), asked every FOLLOW_SECONDS for a
        newer state of it (None: none yet); the viewer then shows that one, at its latest
        frame while "latest frame" is ticked."""
        try:
            import viser
        except ImportError as err:
            raise SurgsplatError("the viewer needs viser: pip install 'surgsplat[viewer]'") from err
        self.run = run
        self.height = height  # None: the browser canvas's height
        self.moving_scale = moving_scale
        self.lock = threading.Lock()
        self.last: ViewerFrame | None = None
        self.frames_sent = 0
        self._idle_timers: dict[int, threading.Timer] = {}
        check_can_serve(host, port)
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.url = http_url(host, self.server.get_port())  # where a browser opens the viewer
        count = len(run.scene.frames)
        gui = self.server.gui
        self.time_slider = gui.add_slider("frame", min=0, max=count - 1, step=1, initial_value=0)
        self.play = gui.add_checkbox("play", initial_value=False)
        self.fps = gui.add_number("play fps", initial_value=fps, min=0.5, max=60.0, step=0.5)
        self.channel = gui.add_dropdown("channel", viewer_channels(run.model), initial_value=RGB)
        for handle in (self.time_slider, self.channel):
            handle.on_update(lambda _: self.refresh_all())
        self.server.on_client_connect(self._connect)
        self._stop = threading.Event()
        self._player = threading.Thread(target=self._play_loop, daemon=True)
        self._player.start()
        if follow is not None:
            self.latest = gui.add_checkbox("latest frame", initial_value=True)
            threading.Thread(target=self._follow_loop, args=(follow,), daemon=True).start()

    def _follow_loop(self, follow: Callable[[], TrainedRun | None]) -> None:
        while not self._stop.wait(FOLLOW_SECONDS):
            newer = follow()
            if newer is None:
                continue
            with self.lock:
                self.run = newer
                last = len(newer.scene.frames) - 1
                self.time_slider.max = last
                if self.latest.value or int(self.time_slider.value) > last:
                    self.time_slider.value = last
            self.refresh_all()

    # ---- cameras ----
    def _connect(self, client) -> None:
        camera = self.run.scene.frames[0].camera
        camera_to_world = camera.camera_to_world.double().numpy()
        rotation, position = camera_to_world[:3, :3], camera_to_world[:3, 3]
        depth = float(self.run.scene.frames[0].depth.median()) \
            if self.run.scene.frames[0].depth is not None else 50.0
        with client.atomic():
            client.camera.wxyz = matrix_to_wxyz(rotation)
            client.camera.position = position
            client.camera.fov = 2.0 * math.atan(camera.height / 2.0 / camera.fy)
            client.camera.look_at = position + rotation @ np.array([0.0, 0.0, depth])
            client.camera.up_direction = -rotation[:, 1]
        client.camera.on_update(lambda _: self._camera_moved(client))
        self.send(client, scale=1.0)

    def client_camera(self, client, scale: float) -> Camera:
        """The pinhole camera of the browser's view, `scale` x the viewer's height."""
        full = self.height or int(client.camera.image_height or 0) or self.run.scene.height
        height = max(16, int(round(full * scale)))
        width = max(16, int(round(height * client.camera.aspect)))
        focal = height / 2.0 / math.tan(client.camera.fov / 2.0)
        K = torch.tensor([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]])
        rotation = quaternion_to_matrix(torch.tensor(client.camera.wxyz, dtype=torch.float32))
        position = torch.tensor(client.camera.position, dtype=torch.float32)
        world_to_camera = torch.eye(4)
        world_to_camera[:3, :3] = rotation.T
        world_to_camera[:3, 3] = -rotation.T @ position
        return Camera(K=K, world_to_camera=world_to_camera, width=width, height=height)

    def _camera_moved(self, client) -> None:
        self.send(client, scale=self.moving_scale)
        timer = self._idle_timers.pop(client.client_id, None)
        if timer is not None:
            timer.cancel()
        timer = threading.Timer(0.3, self.send, args=(client,), kwargs={"scale": 1.0})
        self._idle_timers[client.client_id] = timer
        timer.start()

    # ---- frames ----
    def send(self, client, scale: float) -> None:
        """Render the current frame and channel for `client` and send it."""
        with self.lock:
            started = time.perf_counter()
            index, channel = int(self.time_slider.value), str(self.channel.value)
            image = view_image(self.run, self.client_camera(client, scale), index, channel)
            self.last = ViewerFrame(index, channel, image, time.perf_counter() - started)
            self.frames_sent += 1
        client.scene.set_background_image(image, format="jpeg", jpeg_quality=90)

    def refresh_all(self) -> None:
        for client in self.server.get_clients().values():
            self.send(client, scale=1.0)

    def _play_loop(self) -> None:
        while not self._stop.is_set():
            if self.play.value:
                count = len(self.run.scene.frames)
                self.time_slider.value = (int(self.time_slider.value) + 1) % count
            self._stop.wait(1.0 / max(float(self.fps.value), 0.5))

    def stop(self) -> None:
        self._stop.set()
        for timer in self._idle_timers.values():
            timer.cancel()
        self.server.stop()
