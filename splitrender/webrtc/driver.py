"""Driving the page from Python: a server in a child process and headless Chromium through Playwright.

The tests and ``benchmarks/bench_browser_mtp.py`` use these; a user needs neither (open the page in a
browser).  Playwright drives the system's Chromium (``executable_path``: Debian's ``chromium`` package) and
never downloads one.

Chromium's flags, and why:

* ``--allow-loopback-in-peer-connection``: WebRTC leaves loopback interfaces out of ICE by default, and the
  tests may use loopback only;
* ``--disable-features=WebRtcHideLocalIpsWithMdns``: host candidates as addresses, not mDNS names, which a
  server with no mDNS resolver could not reach;
* ``--autoplay-policy=no-user-gesture-required``: the page's ``<video>`` plays without a click;
* ``--no-sandbox``: the sandbox needs user namespaces that containers often lack.

The viewport is kept small (400x300): with no GPU, Chromium's compositor runs on SwiftShader and costs in
proportion to the page's size (at 1280x720 it took three times the CPU of the page at 400x300, and starved
the server of the machine's two cores).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

__all__ = ["CHROMIUM_ARGS", "find_chromium", "browser_missing", "ServerProcess", "PageDriver"]

CHROMIUM_ARGS = ["--no-sandbox", "--allow-loopback-in-peer-connection", "--disable-features=WebRtcHideLocalIpsWithMdns",
                 "--autoplay-policy=no-user-gesture-required"]
VIEWPORT = {"width": 400, "height": 300}


def find_chromium() -> str | None:
    """The Chromium to drive: ``$SPLITRENDER_CHROMIUM``, else ``chromium`` or ``chromium-browser`` on the PATH."""
    env = os.environ.get("SPLITRENDER_CHROMIUM")
    if env:
        return env if Path(env).exists() else None
    return shutil.which("chromium") or shutil.which("chromium-browser")


def browser_missing() -> str | None:
    """Why a page cannot be driven here (no Chromium, no Playwright), or ``None``."""
    if find_chromium() is None:
        return "no Chromium (install Debian's chromium package, or set SPLITRENDER_CHROMIUM)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "no Python playwright (pip install playwright; it drives the system's Chromium)"
    return None


class ServerProcess:
    """``splitrender serve --webrtc --http 127.0.0.1:0`` (and ``args``) in a child process; ``url`` is the page's,
    ``log`` its newest stderr lines."""

    def __init__(self, args: list[str], start_timeout_s: float = 90.0) -> None:
        self.args = args
        self.start_timeout_s = start_timeout_s
        self.url = ""
        self.proc: subprocess.Popen[str] | None = None
        self.log: deque[str] = deque(maxlen=400)
        self._pump: threading.Thread | None = None

    def __enter__(self) -> ServerProcess:
        cmd = [sys.executable, "-m", "splitrender.cli", "serve", "--port", "0", "--udp-port", "0", "--webrtc",
               "--http", "127.0.0.1:0", *self.args]
        self.proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
        assert self.proc.stderr is not None
        found = threading.Event()

        def pump() -> None:
            assert self.proc is not None and self.proc.stderr is not None
            try:
                for line in self.proc.stderr:
                    self.log.append(line.rstrip())
                    m = re.search(r"browsers: (http://\S+)", line)
                    if m and not found.is_set():
                        self.url = m.group(1)
                        found.set()
            finally:
                found.set()
                self.proc.stderr.close()     # at the child's end (EOF): no pipe left for the garbage collector

        self._pump = threading.Thread(target=pump, daemon=True)
        self._pump.start()
        if not found.wait(self.start_timeout_s) or not self.url:
            self.__exit__()
            raise RuntimeError("the server did not start:\n" + "\n".join(self.log))
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        if self._pump is not None:
            self._pump.join(5)                # it reads the child's stderr to its end and closes it


class PageDriver:
    """Headless Chromium; :meth:`session` loads the page with a session's URL parameters and waits for its end."""

    def __init__(self, executable: str | None = None) -> None:
        self.executable = executable or find_chromium()
        self._pw: Any = None
        self.browser: Any = None
        self.page: Any = None
        self.console: deque[str] = deque(maxlen=200)

    def __enter__(self) -> PageDriver:
        from playwright.sync_api import sync_playwright

        self._pw = sync_playwright().start()
        self.browser = self._pw.chromium.launch(executable_path=self.executable, args=CHROMIUM_ARGS)
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.browser is not None:
            self.browser.close()
        if self._pw is not None:
            self._pw.stop()

    def session(self, url: str, method: str, trace: str = "turn", duration_s: float = 5.0, width: int = 320,
                height: int = 180, record_every: int = 4, timeout_s: float = 120.0, **extra: Any) -> dict[str, Any]:
        """One session in a fresh page; returns the page's result (``ok``, ``session_id``, ``stats``, ...)."""
        if self.page is not None:
            self.page.close()
        self.page = self.browser.new_page(viewport=VIEWPORT)
        self.page.on("console", lambda m: self.console.append(f"{m.type}: {m.text}"))
        query = {"method": method, "trace": trace, "duration": duration_s, "width": width, "height": height,
                 "record_every": record_every, "autostart": 1, **extra}
        self.page.set_default_timeout(timeout_s * 1000)
        t0 = time.monotonic()
        self.page.goto(f"{url}?{urlencode(query)}")
        result = self.page.evaluate("() => window.splitrender.done")
        result["wall_s"] = time.monotonic() - t0
        return result

    def screenshot(self, path: str | Path) -> None:
        """The canvas of the current page as a PNG."""
        self.page.locator("#view").screenshot(path=str(path))
