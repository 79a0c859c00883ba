"""``capture``'s page: served on the loopback interface by the standard library, nothing from elsewhere, the stream,
the state and the buttons; a port in use is one line."""

from __future__ import annotations

import json
import socket
import urllib.request

import numpy as np
import pytest

from ccs_kornia.outputs.capture_page import CapturePage, annotate
from ccs_kornia.runtime.errors import UserError


def _get(url: str, timeout: float = 5.0) -> bytes:
    with urllib.request.urlopen(url, timeout=timeout) as r:
        return r.read()


@pytest.fixture
def page():
    p = CapturePage("127.0.0.1", 0)
    yield p
    p.close()


def test_the_page_serves_the_stream_state_and_buttons(page):
    assert page.url.startswith("http://127.0.0.1:")
    html = _get(page.url).decode()
    assert "/stream.mjpg" in html and "calibrate now" in html
    assert "http://" not in html.replace(page.url, "") and "https://" not in html  # nothing from elsewhere
    heat = np.full((12, 16), 0.05)
    heat[0, 0] = 1.0
    image = annotate(np.full((240, 320), 90, np.uint8), np.array([[40, 40], [120, 40], [120, 100], [40, 100.0]]),
                     [np.array([[10, 10], [60, 10], [60, 50], [10, 50.0]])],
                     np.array([[200, 150], [300, 150], [300, 220], [200, 220.0]]), heat, 0.1, 0.42)
    page.show(image)
    page.set_state(worst_px=0.42, target_px=0.1, instruction="top left, closer", kept=[{"name": "f", "why": "w"}])
    state = json.loads(_get(page.url + "state.json"))
    assert state["worst_px"] == 0.42 and state["instruction"] == "top left, closer" and len(state["kept"]) == 1
    assert _get(page.url + "frame.jpg")[:2] == b"\xff\xd8"
    with urllib.request.urlopen(page.url + "stream.mjpg", timeout=5) as r:
        assert r.headers["Content-Type"].startswith("multipart/x-mixed-replace")
        head = r.read(200)
    assert b"--frame" in head and b"image/jpeg" in head
    for name in ("keep", "undo", "calibrate", "close"):
        urllib.request.urlopen(urllib.request.Request(page.url + name, data=b"", method="POST"), timeout=5).read()
    assert page.take_actions() == ["keep", "undo", "calibrate", "close"] and page.take_actions() == []


def test_a_port_in_use_is_one_line():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(UserError, match=f"--port {port} on 127.0.0.1: in use"):
            CapturePage("127.0.0.1", port)
