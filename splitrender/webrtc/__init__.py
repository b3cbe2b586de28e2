"""The browser front door: WebRTC sessions for a page that draws with WebGL 2.

``splitrender serve --webrtc`` adds an HTTP server (aiohttp) to the live server.  It
serves the page (:mod:`splitrender.webrtc.static`: plain ES modules, no build step), an
offer/answer endpoint, camera traces as JSON, and endpoints the page posts its recording
to.  Each browser session is a :class:`~splitrender.webrtc.session.BrowserSession`: an
aiortc peer connection whose video track carries the method's colour stream, coded by the
same method server half and encoders as the project's own RTP/TCP front door (in the same
render workers), as H.264 Constrained Baseline 4:2:0, which every browser decodes.  Data
channels carry the rest: per-frame metadata (partially reliable), session messages
(reliable, ordered) and poses up (unordered, unreliable).  See ``docs/browser.md``.
"""

from __future__ import annotations

from .messages import BROWSER_METHODS, browser_methods

__all__ = ["BROWSER_METHODS", "browser_methods"]
