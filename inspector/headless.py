"""A tab without a browser, for benches: a websocket client that connects to the inspector's viser
server as the page does, so the server makes a real tab (app.Session: its GUI, scene, redrawers,
tour, gallery) and sends it every message, which this client reads and drops.

viser counts a client as connected once it reports its camera, so the headless tab reports one,
as a page of `size` pixels whose camera looks straight at the photo (the session's own initial
camera). What is measured on such a tab is the server's whole path for a browser tab
(composing, JPEG encoding, queueing onto the tab's own socket); only the browser's decoding and
drawing are missing.

    with HeadlessTab(app) as tab:        # tab: the app.Session
        tab.tour.start(1)
"""

from __future__ import annotations

import threading
import time

import msgspec
import numpy as np
import viser
from viser._messages import ViewerCameraMessage
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect


class HeadlessTab:
    """Connect to `app` (an app.Inspector) as one browser tab; `session` is its Session."""

    def __init__(self, app, size: tuple[int, int] = (1280, 720), timeout: float = 60.0):
        self.app = app
        before = set(app.sessions)
        host = app.server.get_host()
        host = "127.0.0.1" if host in ("0.0.0.0", "", "::") else host
        # the server accepts a client of its own version only (its websocket subprotocol)
        self._ws = connect(f"ws://{host}:{app.server.get_port()}", subprotocols=[f"viser-v{viser.__version__}"],
                           max_size=None, compression=None, open_timeout=timeout)
        self.received = 0                   # messages read (and dropped)
        self._reader = threading.Thread(target=self._drain, name="headless-tab", daemon=True)
        self._reader.start()
        w, h = size                 # OpenCV camera axes, looking along +z with -y up: no rotation
        cam = ViewerCameraMessage(wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, -1.6), fov=float(np.deg2rad(75.0)),
                                  near=0.01, far=1000.0, image_height=h, image_width=w, look_at=(0.0, 0.0, 0.0),
                                  up_direction=(0.0, -1.0, 0.0))
        self._ws.send(msgspec.msgpack.encode(cam.as_serializable_dict()))
        t0 = time.time()
        while not set(app.sessions) - before:
            if time.time() - t0 > timeout:
                self.close()
                raise TimeoutError("the inspector made no session for the headless tab")
            time.sleep(0.01)
        self.session = app.sessions[(set(app.sessions) - before).pop()]

    def _drain(self) -> None:
        try:
            for _ in self._ws:
                self.received += 1
        except ConnectionClosed:
            pass

    def close(self) -> None:
        self._ws.close()
        self._reader.join(timeout=10)

    def __enter__(self):
        return self.session

    def __exit__(self, *exc) -> None:
        self.close()
