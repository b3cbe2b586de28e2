"""Live asyncio server: sessions, frame clock, RTP/RTCP transport (see server.py)."""
