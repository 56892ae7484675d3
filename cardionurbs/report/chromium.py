"""Open a local HTML file in headless Chromium and record what it did (stdlib only).

Used by the report tests and the report-assembly script: it loads the page
through the Chrome DevTools Protocol (a minimal RFC 6455 WebSocket client over
a plain socket, no third-party dependency), and returns

* every console message and uncaught exception (``errors``: console
  ``error``/``assert`` calls, exceptions, browser log entries of level
  ``error`` such as CSP violations or failed loads);
* every network request the page made other than its own ``file:`` URL and
  inline ``data:``/``blob:`` resources (``requests``);
* a PNG screenshot, and the value of a JavaScript expression evaluated after
  the page reports it is ready.

Chromium runs with ``--headless --no-sandbox --disable-gpu`` (software WebGL
through SwiftShader), no first-run, background networking, component update
or sync, a fresh ``--user-data-dir``, and a host resolver that maps every
name to NOTFOUND, so nothing can reach the network even if the page tried.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import socket
import struct
import subprocess
import tempfile
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

from cardionurbs.errors import ChromiumError

__all__ = ["find_chromium", "open_page", "PageRun", "ChromiumError", "CHROMIUM_FLAGS"]

CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync",
                  "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
                  "--disable-extensions", "--mute-audio", "--hide-scrollbars",
                  "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1")


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable (``CHROMIUM`` env var first), or None.

    Returns
    -------
    str or None
        The executable's path, None when none is installed.
    """
    env = os.environ.get("CHROMIUM")
    if env and Path(env).is_file():
        return env
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        p = shutil.which(name)
        if p:
            return p
    return None


# ------------------------------------------------------------- websocket
class _WebSocket:
    """Just enough RFC 6455 for CDP: masked text frames out, (fragmented) frames in."""

    def __init__(self, url: str, timeout: float) -> None:
        assert url.startswith("ws://")
        hostport, _, path = url[5:].partition("/")
        host, _, port = hostport.partition(":")
        self.sock = socket.create_connection((host, int(port)), timeout=timeout)
        key = base64.b64encode(os.urandom(16)).decode()
        req = (f"GET /{path} HTTP/1.1\r\nHost: {hostport}\r\nUpgrade: websocket\r\n"
               f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n")
        self.sock.sendall(req.encode())
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise ChromiumError("DevTools websocket closed during the handshake")
            head += chunk
        status, _, rest = head.partition(b"\r\n\r\n")
        if b" 101 " not in status.split(b"\r\n")[0]:
            raise ChromiumError(f"DevTools websocket handshake refused: {status[:80]!r}")
        self.buf = rest

    def _read(self, n: int) -> bytes:
        while len(self.buf) < n:
            chunk = self.sock.recv(max(65536, n - len(self.buf)))
            if not chunk:
                raise ChromiumError("DevTools websocket closed")
            self.buf += chunk
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def send(self, text: str) -> None:
        data = text.encode()
        head = bytearray([0x81])
        n = len(data)
        if n < 126:
            head.append(0x80 | n)
        elif n < 65536:
            head.append(0x80 | 126)
            head += struct.pack(">H", n)
        else:
            head.append(0x80 | 127)
            head += struct.pack(">Q", n)
        mask = os.urandom(4)
        body = bytes(b ^ mask[i % 4] for i, b in enumerate(data))
        self.sock.sendall(bytes(head) + mask + body)

    def recv(self) -> str:
        parts = []
        while True:
            b0, b1 = self._read(2)
            fin, op = b0 & 0x80, b0 & 0x0F
            n = b1 & 0x7F
            if n == 126:
                n = struct.unpack(">H", self._read(2))[0]
            elif n == 127:
                n = struct.unpack(">Q", self._read(8))[0]
            mask = self._read(4) if b1 & 0x80 else None
            payload = self._read(n)
            if mask:
                payload = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
            if op == 0x8:
                raise ChromiumError("DevTools websocket closed by the browser")
            if op == 0x9:                                   # ping -> pong
                self.sock.sendall(bytes([0x8A, 0x80 | len(payload)]) + b"\0\0\0\0" + payload)
                continue
            parts.append(payload)
            if fin:
                return b"".join(parts).decode("utf-8", "replace")

    def close(self) -> None:
        try:
            self.sock.close()
        except OSError:
            pass


class _Session:
    """CDP commands with ids; events are kept in order."""

    def __init__(self, ws: _WebSocket) -> None:
        self.ws, self.next_id = ws, 0
        self.events: list[dict] = []

    def call(self, method: str, **params) -> dict:
        self.next_id += 1
        mid = self.next_id
        self.ws.send(json.dumps({"id": mid, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv())
            if msg.get("id") == mid:
                if "error" in msg:
                    raise ChromiumError(f"{method}: {msg['error'].get('message')}")
                return msg.get("result", {})
            if "method" in msg:
                self.events.append(msg)

    def pump(self, seconds: float) -> None:
        """Collect events for ``seconds`` (a no-op command keeps the loop bounded)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.call("Runtime.evaluate", expression="1")
            time.sleep(0.05)


# ------------------------------------------------------------- page run
@dataclass
class PageRun:
    """What happened when a page was opened (see module doc).

    Attributes
    ----------
    url : str
        The ``file://`` URL opened.
    ready : bool
        Whether ``ready_js`` became true before the timeout.
    value : object
        What ``value_js`` returned (JSON-like), None without it.
    errors : list of str
        Console errors, assertions, uncaught exceptions and error log entries.
    console : list of str
        Every console message and log entry.
    requests : list of str
        Network requests to anything but the page itself (and data:, blob: URLs).
    screenshot : bytes
        The PNG screenshot taken once ready.
    seconds : float
        Wall time of the run, in s.
    """

    url: str
    ready: bool
    value: object
    errors: list[str] = field(default_factory=list)
    console: list[str] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)
    screenshot: bytes = b""
    seconds: float = 0.0


def _own(url: str, page_url: str) -> bool:
    return url == page_url or url.startswith(("data:", "blob:", "about:", "chrome-error:"))


def open_page(path: str | Path, *, chromium: str | None = None, width: int = 1400,
              height: int = 1000, ready_js: str = "document.readyState === 'complete'",
              value_js: str | None = None, timeout: float = 60.0, settle: float = 0.8
              ) -> PageRun:
    """Open ``path`` in headless Chromium; wait until ``ready_js`` is truthy (or timeout), screenshot,
    then evaluate ``value_js`` (may return a promise); report errors and requests seen meanwhile.

    Parameters
    ----------
    path : path-like (the HTML file)
    chromium, ready_js, value_js : str (executable, default :func:`find_chromium`; JavaScript)
    width, height : int (window size, CSS pixels)
    timeout, settle : float (longest wait; time from ready to the screenshot; in s)

    Returns
    -------
    PageRun
        What happened (no browser, or none answering: :class:`~cardionurbs.errors.ChromiumError`)."""
    exe = chromium or find_chromium()
    if not exe:
        raise ChromiumError("no chromium executable found (apt-get install chromium)")
    page_url = Path(path).resolve().as_uri()
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="cn-chromium-") as prof:
        cmd = [exe, *CHROMIUM_FLAGS, f"--user-data-dir={prof}", "--remote-debugging-port=0",
               f"--window-size={width},{height}", "about:blank"]
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True)
        ws = None
        try:
            port_file = Path(prof) / "DevToolsActivePort"
            while not port_file.is_file() or not port_file.read_text().strip():
                if proc.poll() is not None:
                    raise ChromiumError(f"chromium exited with code {proc.returncode} at start")
                if time.monotonic() - t0 > timeout:
                    raise ChromiumError("chromium did not open its DevTools port in time")
                time.sleep(0.05)
            port = int(port_file.read_text().split()[0])
            targets: list[dict] = []
            while not targets:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
                    targets = [t for t in json.load(r) if t.get("type") == "page"]
                if not targets:
                    time.sleep(0.05)
            ws = _WebSocket(targets[0]["webSocketDebuggerUrl"], timeout=timeout)
            s = _Session(ws)
            for dom in ("Page", "Runtime", "Log", "Network"):
                s.call(f"{dom}.enable")
            s.call("Emulation.setDeviceMetricsOverride", width=width, height=height,
                   deviceScaleFactor=1, mobile=False)
            s.call("Page.navigate", url=page_url)
            ready = False
            while time.monotonic() - t0 < timeout:
                r = s.call("Runtime.evaluate", expression=f"Boolean({ready_js})", returnByValue=True)
                if r.get("result", {}).get("value") is True:
                    ready = True
                    break
                time.sleep(0.1)
            s.pump(settle)
            shot = base64.b64decode(s.call("Page.captureScreenshot", format="png")["data"])
            value = None
            if value_js:                          # after the screenshot: it may change the page
                value = s.call("Runtime.evaluate", expression=value_js, awaitPromise=True,
                               returnByValue=True).get("result", {}).get("value")
                s.pump(0.2)
            run = PageRun(page_url, ready, value, screenshot=shot)
            for ev in s.events:
                m, p = ev["method"], ev.get("params", {})
                if m == "Runtime.consoleAPICalled":
                    text = " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", []))
                    run.console.append(f"{p.get('type')}: {text}")
                    if p.get("type") in ("error", "assert"):
                        run.errors.append(f"console.{p.get('type')}: {text}")
                elif m == "Runtime.exceptionThrown":
                    d = p.get("exceptionDetails", {})
                    run.errors.append("exception: " + str(d.get("exception", {}).get("description")
                                                          or d.get("text")))
                elif m == "Log.entryAdded":
                    e = p.get("entry", {})
                    run.console.append(f"log {e.get('level')}: {e.get('text')}")
                    if e.get("level") == "error":
                        run.errors.append(f"log error: {e.get('text')} ({e.get('url', '')})")
                elif m == "Network.requestWillBeSent":
                    url = p.get("request", {}).get("url", "")
                    if not _own(url, page_url):
                        run.requests.append(url)
            run.seconds = time.monotonic() - t0
            try:
                s.call("Browser.close")
            except ChromiumError:
                pass
            return run
        finally:
            if ws is not None:
                ws.close()
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5)
