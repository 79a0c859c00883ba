"""``capture``'s local page: the live image with the board, the coverage so far, the predicted uncertainty map with the
figure that decides and the target, the suggested pose's outline and instruction, the kept frames with why, and the
keep / undo / calibrate-now / close buttons (keys k, u, c, q).

Served by the standard library (:class:`http.server.ThreadingHTTPServer` on a daemon thread): ``/`` the page (no
script or style from elsewhere: it works without internet), ``/stream.mjpg`` the annotated frames as an MJPEG stream,
``/state.json`` the figures and the kept frames, ``POST /keep``, ``/undo``, ``/calibrate``, ``/close`` the buttons. It listens on
the loopback interface unless another host is given.
"""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import cv2
import numpy as np

from ccs_kornia.runtime.errors import UserError

__all__ = ["CapturePage", "annotate"]

_PAGE = """<!doctype html>
<html><head><meta charset="utf-8"><title>ccs_kornia capture</title>
<style>
body{font-family:sans-serif;margin:0;display:flex;background:#111;color:#eee}
#live{flex:3;padding:8px} #live img{width:100%;height:auto;background:#000}
#side{flex:1;padding:8px;min-width:280px}
.figure{font-size:28px} .done{color:#6f6} .next{font-size:18px;color:#ffb000;margin:8px 0}
button{font-size:16px;margin:4px 4px 4px 0;padding:6px 12px}
li{font-size:13px;margin:2px 0}
</style></head><body>
<div id="live"><img id="stream" src="/stream.mjpg" alt="live image"></div>
<div id="side">
<div>predicted worst 1-sigma over the image</div>
<div class="figure"><span id="figure">-</span> px <small>(target <span id="target">-</span> px)</small></div>
<div id="status"></div>
<div class="next">next: <span id="next">-</span></div>
<button onclick="act('keep')">keep (k)</button><button onclick="act('undo')">undo (u)</button>
<button onclick="act('calibrate')">calibrate now (c)</button><button onclick="act('close')">close (q)</button>
<h4>kept frames: <span id="count">0</span></h4><ol id="kept"></ol>
</div>
<script>
function act(what){fetch('/'+what,{method:'POST'});}
document.addEventListener('keydown',e=>{const k={k:'keep',u:'undo',c:'calibrate',q:'close'}[e.key];if(k)act(k);});
async function poll(){
 try{const s=await (await fetch('/state.json')).json();
  document.getElementById('figure').textContent=s.worst_px===null?'-':s.worst_px.toFixed(3);
  document.getElementById('target').textContent=s.target_px;
  document.getElementById('next').textContent=s.instruction||'-';
  const st=document.getElementById('status');st.textContent=s.status;st.className=s.done?'done':'';
  document.getElementById('count').textContent=s.kept.length;
  document.getElementById('kept').innerHTML=s.kept.map(k=>'<li>'+k.name+': '+k.why+'</li>').join('');
 }catch(e){}
 setTimeout(poll,250);}
poll();
</script></body></html>
"""


def _heat(values: np.ndarray, target: float, size: tuple[int, int]) -> np.ndarray:
    """The uncertainty map :math:`(down, across)` px as a BGR image of ``size``: green at or below the target, red at
    four times it and above."""
    v = np.nan_to_num(values, nan=4 * target) / max(target, 1e-9)
    t = np.clip((v - 1.0) / 3.0, 0.0, 1.0)
    bgr = np.stack([np.zeros_like(t), (1 - t) * 200 + 40 * (v <= 1), t * 230], -1).astype(np.uint8)
    return cv2.resize(bgr, size, interpolation=cv2.INTER_NEAREST)


def annotate(gray8: np.ndarray, outline: np.ndarray | None, coverage: list[np.ndarray],
             suggested: np.ndarray | None, heat: np.ndarray | None, target: float, worst: float | None,
             caption: str = "") -> np.ndarray:
    """The live frame as the page shows it (BGR): the kept boards' outlines filled (coverage), the board seen now
    (green), the suggested pose's outline (orange), the uncertainty map inset at the top right with its figure, and a
    ``caption`` at the top left (a rig's camera: its name and the views in common it still needs).

    Example:
        >>> img = annotate(np.zeros((120, 160), np.uint8), np.array([[10, 10], [50, 10], [50, 40], [10, 40.]]), [],
        ...                None, None, 0.1, None)
        >>> img.shape, int(img[10, 30, 1]) > 0
        ((120, 160, 3), True)
    """
    img = cv2.cvtColor(gray8, cv2.COLOR_GRAY2BGR)
    if coverage:
        layer = img.copy()
        for quad in coverage:
            cv2.fillPoly(layer, [np.round(quad).astype(np.int32)], (255, 120, 0))
        img = cv2.addWeighted(layer, 0.3, img, 0.7, 0)
    h, w = gray8.shape
    thick = max(1, round(max(h, w) / 400))
    if suggested is not None:
        cv2.polylines(img, [np.round(suggested).astype(np.int32)], True, (0, 165, 255), 2 * thick)
    if outline is not None:
        cv2.polylines(img, [np.round(outline).astype(np.int32)], True, (0, 255, 0), thick)
        for p in outline:
            cv2.circle(img, (round(float(p[0])), round(float(p[1]))), 3 * thick, (0, 255, 0), -1)
    if heat is not None:
        iw, ih = w // 4, h // 4
        img[4:4 + ih, w - iw - 4:w - 4] = _heat(heat, target, (iw, ih))
        text = "-" if worst is None else f"{worst:.3f} px / {target:g}"
        cv2.putText(img, text, (w - iw - 4, 8 + ih + 12 * thick), cv2.FONT_HERSHEY_SIMPLEX, 0.4 * thick,
                    (255, 255, 255), thick, cv2.LINE_AA)
    if caption:
        cv2.putText(img, caption, (6, 6 + 12 * thick), cv2.FONT_HERSHEY_SIMPLEX, 0.4 * thick, (255, 255, 255), thick,
                    cv2.LINE_AA)
    return img


class CapturePage:
    """The page's server and what it shows (:meth:`show`, :meth:`set_state`), and the buttons pressed
    (:meth:`take_actions`).

    Args:
        host: the interface to listen on (``127.0.0.1``: this machine only).
        port: the port (0: any free one).
        quality: JPEG quality of the stream.

    Raises:
        UserError: the port is in use or the host cannot be listened on (one line).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, quality: int = 80) -> None:
        self._lock = threading.Condition()
        self._jpeg: bytes | None = None
        self._seq = 0
        self._state: dict = {"worst_px": None, "target_px": None, "instruction": "", "status": "", "kept": [],
                             "done": False}
        self._actions: list[str] = []
        self.quality = int(quality)
        self.closed = False
        page = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args) -> None:  # the console is capture's
                pass

            def _send(self, body: bytes, kind: str) -> None:
                self.send_response(200)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def do_GET(self) -> None:
                if self.path == "/":
                    self._send(_PAGE.encode(), "text/html; charset=utf-8")
                elif self.path == "/state.json":
                    with page._lock:
                        body = json.dumps(page._state).encode()
                    self._send(body, "application/json")
                elif self.path == "/frame.jpg":
                    with page._lock:
                        body = page._jpeg or b""
                    self._send(body, "image/jpeg")
                elif self.path == "/stream.mjpg":
                    self._stream()
                else:
                    self.send_error(404)

            def do_POST(self) -> None:
                name = self.path.strip("/")
                if name not in ("keep", "undo", "calibrate", "close"):
                    self.send_error(404)
                    return
                with page._lock:
                    page._actions.append(name)
                self._send(b"{}", "application/json")

            def _stream(self) -> None:
                self.send_response(200)
                self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                last = [-1]  # the frame sent last
                try:
                    while not page.closed:
                        with page._lock:
                            page._lock.wait_for(lambda: page._seq != last[0] or page.closed, timeout=1.0)
                            body, last[0] = page._jpeg, page._seq
                        if body is None:
                            continue
                        self.wfile.write(b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: "
                                         + str(len(body)).encode() + b"\r\n\r\n" + body + b"\r\n")
                except (BrokenPipeError, ConnectionResetError):
                    return

        try:
            self._server = ThreadingHTTPServer((host, int(port)), Handler)
        except OSError as err:
            what = "in use" if err.errno in (98, 48, 10048) else (err.strerror or str(err))
            raise UserError(f"--port {port} on {host}: {what}") from None
        self._server.daemon_threads = True
        self.host, self.port = self._server.server_address[:2]
        self._thread = threading.Thread(target=self._server.serve_forever, name="capture-page", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    def show(self, image_bgr: np.ndarray) -> None:
        """The next frame of the stream."""
        ok, buf = cv2.imencode(".jpg", image_bgr, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        if not ok:
            return
        with self._lock:
            self._jpeg = buf.tobytes()
            self._seq += 1
            self._lock.notify_all()

    def set_state(self, **state) -> None:
        with self._lock:
            self._state.update(state)

    def take_actions(self) -> list[str]:
        """The buttons pressed since the last call, in order."""
        with self._lock:
            out, self._actions = self._actions, []
        return out

    def close(self) -> None:
        self.closed = True
        with self._lock:
            self._lock.notify_all()
        self._server.shutdown()
        self._server.server_close()
