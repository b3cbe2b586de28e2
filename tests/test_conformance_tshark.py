"""RTCP as Wireshark's ``tshark`` reads it: a second, independent RTCP parser (issue 37, conformance).

The server's sender reports must be compound packets (RFC 3550 6.1): one SR per RTP stream, then an
SDES whose chunks carry the session's CNAME (``splitrender-server-<ssrc>``) for every stream; the
client's feedback is an RR, its SDES CNAME, then NACKs and PLIs (RFC 4585 3.1).  The datagrams are the
ones the sans-IO session cores build (the live server and client only move those bytes); they go into
a classic pcap file (Ethernet, IPv4, UDP on loopback addresses; no network is used) that tshark
dissects as RTCP, and every packet must come out whole: no malformed packet, no expert warning or error.

Skipped when ``tshark`` is not installed (Debian: ``apt-get install tshark``; ``.ci/run`` installs it).
"""

from __future__ import annotations

import shutil
import struct
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from splitrender.codecs.video import VideoCodecConfig
from splitrender.methods import StreamSpec, Update
from splitrender.pipeline import ClientOptions, ClientSession, ServerOptions, ServerPipeline, ServerSession, StreamEncoder
from splitrender.protocol import RtpPacket, Welcome
from splitrender.scene.pose import Pose

TSHARK = shutil.which("tshark")
pytestmark = pytest.mark.skipif(TSHARK is None, reason="tshark (Wireshark) is not installed: no independent RTCP parser")

SERVER_PORT, CLIENT_PORT = 5004, 40000
LOOPBACK = bytes([127, 0, 0, 1])
W, H, FPS = 64, 48, 30.0
EXPERT_WARN = 0x600000  # Wireshark's PI_WARN; PI_ERROR is 0x800000
FIELDS = ("frame.number", "udp.srcport", "rtcp.pt", "rtcp.senderssrc", "rtcp.sender.packetcount", "rtcp.sc",
          "rtcp.ssrc.identifier", "rtcp.sdes.type", "rtcp.sdes.text", "rtcp.rtpfb.nack_pid", "rtcp.length_check",
          "_ws.malformed", "_ws.expert.severity", "_ws.expert.message")


# --------------------------------------------------------------------------- pcap and tshark


def _ipv4_checksum(header: bytes) -> int:
    s = sum(struct.unpack(f"!{len(header) // 2}H", header))
    while s >> 16:
        s = (s & 0xFFFF) + (s >> 16)
    return ~s & 0xFFFF


def write_pcap(path: Path, datagrams: list[tuple[float, int, int, bytes]]) -> None:
    """A classic pcap (LINKTYPE_ETHERNET) of UDP datagrams ``(time_ms, src_port, dst_port, payload)`` between
    127.0.0.1 and itself; IPv4 header checksums are right, UDP checksums 0 (none, allowed over IPv4)."""
    out = bytearray(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))
    for i, (t_ms, sport, dport, payload) in enumerate(datagrams):
        udp = struct.pack("!HHHH", sport, dport, 8 + len(payload), 0) + payload
        ip = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), i & 0xFFFF, 0x4000, 64, 17, 0, LOOPBACK, LOOPBACK)
        ip = ip[:10] + struct.pack("!H", _ipv4_checksum(ip)) + ip[12:]
        frame = bytes(6) + bytes([2, 0, 0, 0, 0, 1]) + b"\x08\x00" + ip + udp
        us = int(round(t_ms * 1000))
        out += struct.pack("<IIII", us // 1_000_000, us % 1_000_000, len(frame), len(frame)) + frame
    path.write_bytes(bytes(out))


def tshark_fields(path: Path, fields: tuple[str, ...] = FIELDS) -> list[dict[str, list[str]]]:
    """Per frame, every occurrence of each of ``fields`` as tshark decodes the capture (UDP on the
    server's port as RTCP)."""
    assert TSHARK is not None
    cmd = [TSHARK, "-n", "-r", str(path), "-d", f"udp.port=={SERVER_PORT},rtcp", "-T", "fields",
           "-E", "separator=|", "-E", "aggregator=;", "-E", "occurrence=a"]
    for f in fields:
        cmd += ["-e", f]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    rows = []
    for line in res.stdout.splitlines():
        values = line.split("|")
        assert len(values) == len(fields), line
        rows.append({f: (v.split(";") if v else []) for f, v in zip(fields, values)})
    return rows


def assert_whole(row: dict[str, list[str]]) -> None:
    """tshark found nothing wrong with this frame: not malformed, no expert warning or error, lengths right."""
    frame = row["frame.number"]
    assert not row["_ws.malformed"], (frame, row["_ws.expert.message"])
    bad = [m for s, m in zip(row["_ws.expert.severity"], row["_ws.expert.message"]) if int(s) >= EXPERT_WARN]
    assert not bad, (frame, bad)
    assert row["rtcp.length_check"] == ["1"], (frame, row["rtcp.length_check"])


# --------------------------------------------------------------------------- a session's RTCP, both ways


def _session_rtcp() -> dict[str, Any]:
    """Two streams (H.264 colour, lossless HEVC depth as the warp method sends it) for three seconds:
    the server's SR compounds and the client's RR compounds (one RTP packet of frame 1 lost, so NACKs)."""
    depth = VideoCodecConfig("hevc", pix_fmt="gray", input_format="gray", lossless=True, crf=None)
    specs: list[Any] = [StreamSpec("color", VideoCodecConfig("h264", gop=300), W, H), StreamSpec("depth", depth, W, 2 * H)]
    tx, encoder = ServerPipeline(specs, mtu=300, rng=np.random.default_rng(1)), StreamEncoder(specs)
    encoder.open()
    tx.described_sets.update(encoder.described_sets())
    welcome = Welcome("s", "x", tx.welcome_params(b""), tx.describe("127.0.0.1", SERVER_PORT, "t"))
    client = ClientSession.from_welcome(welcome, ClientOptions(), rng=np.random.default_rng(2))
    server = ServerSession(tx, FPS, ServerOptions(), rng=np.random.default_rng(3))
    server.start(0.0)
    client.start(0.0)
    rng = np.random.default_rng(4)
    capture: list[tuple[float, int, int, bytes]] = []
    lost: list[int] = []

    def client_sends(now: float) -> None:
        capture.extend((now, CLIENT_PORT, SERVER_PORT, d) for d in client.datagrams_to_send())

    for fid in range(3):
        now = fid * 1000 / FPS
        planes = {"color": (rng.random((H, W, 3)) * 255).astype(np.uint8),
                  "depth": (rng.random((2 * H, W)) * 255).astype(np.uint8)}
        enc = encoder.encode(Update(fid, fid / FPS, Pose(), planes, {}), force_idr=fid == 0)
        out = tx.packetize(enc, lambda m: b"", 1_000_000 + fid, fid * 3000, 0, fid, fid / FPS, {}, {})
        server.frame_sent(fid, out, now, 1_000_000 + fid)
        media = [d.data for d in server.datagrams_to_send(now) if d.kind == "rtp"]   # the core's one way out
        for k, data in enumerate(media):
            if fid == 1 and k == 1:
                lost.append(RtpPacket.parse(data).sequence_number)
                continue
            client.receive_datagram(data, now + 1.0)
        client_sends(now + 1.0)
    for t in np.arange(0.0, 3000.0, 10.0):
        now = float(t)
        for data in (d.data for d in server.datagrams_to_send(now) if d.kind == "rtcp"):
            capture.append((now, SERVER_PORT, CLIENT_PORT, data))
            client.receive_datagram(data, now + 0.5)  # so the client's RRs carry LSR/DLSR
        client.handle_timer(now)
        client_sends(now)
    capture.sort(key=lambda c: c[0])
    return {"capture": capture, "server": server, "client": client, "tx": tx, "lost": lost}


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    got = _session_rtcp()
    path = tmp_path_factory.mktemp("tshark") / "session_rtcp.pcap"
    write_pcap(path, got["capture"])
    got["rows"] = tshark_fields(path)
    assert len(got["rows"]) == len(got["capture"])
    return got


def test_tshark_reads_every_sender_report_as_sr_then_sdes_cname(session: dict[str, Any]) -> None:
    server, tx = session["server"], session["tx"]
    ssrcs = [st.ssrc for st in server.streams.values()]
    packets = [tx.streams[name].packetizer.packets_sent for name in server.streams]
    cname = server.cname.decode("ascii")
    assert cname == f"splitrender-server-{min(ssrcs):08x}"
    rows = [r for r in session["rows"] if r["udp.srcport"] == [str(SERVER_PORT)]]
    assert len(rows) >= 2, "expected a sender report about every second"
    for row in rows:
        assert_whole(row)
        # one SR per stream, then one SDES: RFC 3550 6.1's compound packet, the report first
        assert row["rtcp.pt"] == ["200"] * len(ssrcs) + ["202"], row
        assert [int(x, 16) for x in row["rtcp.senderssrc"]] == ssrcs
        assert [int(x) for x in row["rtcp.sender.packetcount"]] == packets
        # the SDES: a chunk per stream (SSRC = the SR's), each with CNAME (type 1) and the END item (0)
        assert row["rtcp.sc"] == [str(len(ssrcs))]
        assert [int(x, 16) for x in row["rtcp.ssrc.identifier"]] == ssrcs
        assert row["rtcp.sdes.type"] == ["1", "0"] * len(ssrcs)
        assert row["rtcp.sdes.text"] == [cname] * len(ssrcs)


def test_tshark_reads_every_client_report_as_rr_then_sdes_cname_then_feedback(session: dict[str, Any]) -> None:
    client = session["client"]
    cname = client.cname.decode("ascii")
    rows = [r for r in session["rows"] if r["udp.srcport"] == [str(CLIENT_PORT)]]
    assert len(rows) >= 3
    nacked: set[int] = set()
    for row in rows:
        assert_whole(row)
        pts = row["rtcp.pt"]
        assert pts[:2] == ["201", "202"], row  # RR first, then SDES (RFC 4585 3.1), then feedback
        assert set(pts[2:]) <= {"205", "206"}, row
        assert row["rtcp.senderssrc"][0] == f"0x{client.ssrc:08x}"
        assert row["rtcp.sdes.type"] == ["1", "0"] and row["rtcp.sdes.text"] == [cname]
        nacked.update(int(x) for x in row["rtcp.rtpfb.nack_pid"])
    assert session["lost"] and set(session["lost"]) <= nacked, (session["lost"], nacked)


def test_the_tshark_check_catches_malformed_rtcp(tmp_path: Path) -> None:
    """The checks above are not vacuous: tshark flags a truncated SR and an SDES item that runs past its packet."""
    path = tmp_path / "bad.pcap"
    good_sr = b"\x80\xc8\x00\x06" + bytes(24)
    write_pcap(path, [(0.0, SERVER_PORT, CLIENT_PORT, b"\x80\xc8\x00\x06" + bytes(20)),
                      (1.0, SERVER_PORT, CLIENT_PORT, good_sr + b"\x81\xca\x00\x02" + b"\x00\x00\x00\x01" + b"\x01\x09ab\x00"),
                      (2.0, SERVER_PORT, CLIENT_PORT, good_sr + b"\x81\xca\x00\x03\x00\x00\x00\x01\x01\x03abc\x00\x00\x00")])
    rows = tshark_fields(path)
    for row in rows[:2]:
        with pytest.raises(AssertionError):
            assert_whole(row)
    assert_whole(rows[2])
    assert rows[2]["rtcp.pt"] == ["200", "202"] and rows[2]["rtcp.sdes.text"] == ["abc"]


TWCC_FIELDS = FIELDS + ("rtcp.rtpfb.fmt", "rtcp.rtpfb.transportcc.baseseq", "rtcp.rtpfb.transportcc.statuscount",
                        "rtcp.rtpfb.transportcc.reftime", "rtcp.rtpfb.transportcc.pktcount",
                        "rtcp.rtpfb.transportcc.recv_delta", "rtcp.rtpfb.transportcc_bad")


def test_tshark_reads_transport_cc_feedback_as_we_write_it(tmp_path: Path) -> None:
    """The receiver's transport-cc feedback (issue 35) in an RR compound, as tshark reads it: base sequence, status
    count, reference time and feedback count as written, a receive delta per received packet, nothing malformed.
    Arrivals cover losses, a run, a 0/1 pattern, 2-byte deltas, a negative delta and the sequence wrap."""
    from splitrender.protocol.rtcp import ReceiverReport, serialize_rtcp
    from splitrender.protocol.twcc import FeedbackRecorder

    rec = FeedbackRecorder(ssrc=0x1234, media_ssrc=0x5678)
    seq, t_us, received = 65500, 2_000_000, []
    for i in range(120):
        if i % 7 != 3:                                   # every 7th lost
            arrival = t_us + (-3_000 if i == 50 else 0)  # one arrives 3 ms before the previous: negative delta
            rec.on_packet((seq + i) & 0xFFFF, arrival)
            received.append(i)
        t_us += 500 if i < 40 else 70_000 if i % 10 == 0 else 2_000
    fbs = rec.feedback()
    capture = [(float(k), CLIENT_PORT, SERVER_PORT, serialize_rtcp([ReceiverReport(0x1234, ()), fb])) for k, fb in enumerate(fbs)]
    path = tmp_path / "twcc.pcap"
    write_pcap(path, capture)
    rows = tshark_fields(path, TWCC_FIELDS)
    assert len(rows) == len(fbs) >= 1
    deltas = 0
    for row, fb in zip(rows, fbs):
        assert_whole(row)
        assert not row["rtcp.rtpfb.transportcc_bad"]
        assert row["rtcp.pt"] == ["201", "205"] and row["rtcp.rtpfb.fmt"] == ["15"]
        assert row["rtcp.rtpfb.transportcc.baseseq"] == [str(fb.base_seq)]
        assert row["rtcp.rtpfb.transportcc.statuscount"] == [str(len(fb.arrivals))]
        assert row["rtcp.rtpfb.transportcc.reftime"] == [str(fb.reference_time)]
        assert row["rtcp.rtpfb.transportcc.pktcount"] == [str(fb.fb_count)]
        deltas += len(row["rtcp.rtpfb.transportcc.recv_delta"])
    assert fbs[0].base_seq == 65500 and sum(len(f.arrivals) for f in fbs) == 120  # every status to the last received
    assert deltas == len(received)
