"""Benchmark the shaping relay on loopback: throughput and added latency.

Measures, in the same run and the same process, a direct UDP path (client -> echo
server) and the same path through :class:`splitrender.netsim.Relay` with the ``ideal``
profile (so only the relay's own cost is measured):

* throughput: ``--packets`` echoed datagrams of ``--size`` bytes with at most
  ``--window`` in flight; packets/s and payload Mbit/s (one direction);
* latency: ``--pings`` sequential ping-pongs; one-way latency = RTT / 2 (ms), median
  and p99; the relay's *added* one-way latency is the difference of the medians.

The client and the echo server share one process and event loop; the relay runs in a
second process, as ``splitrender shape`` would.  A warm-up run precedes ``--repeats``
alternating runs per path; the medians are reported.  Every loop is bounded in count
and time.
Writes ``benchmarks/results/bench_relay.json``.

    python benchmarks/bench_relay.py [--packets 20000] [--size 1200] [--pings 1000]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import json
import logging
import multiprocessing
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout
from splitrender.netsim import Relay, get_profile  # noqa: E402

logger = logging.getLogger(__name__)
LO = "127.0.0.1"
TIME_LIMIT_S = 30.0  # per measurement


class _Echo(asyncio.DatagramProtocol):
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.transport.sendto(data, addr)  # type: ignore[attr-defined]


class _Client(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.received = 0
        self.event = asyncio.Event()

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.received += 1
        self.event.set()


async def _measure(endpoint: tuple[asyncio.DatagramTransport, _Client], packets: int,
                   size: int, window: int, pings: int) -> dict[str, Any]:
    loop = asyncio.get_running_loop()
    transport, client = endpoint
    payload = bytes(size)
    # latency: one packet in flight; a lost ping is skipped after 0.2 s
    rtts = []
    async with asyncio.timeout(TIME_LIMIT_S):
        for _ in range(pings):
            client.event.clear()
            before = client.received
            t0 = time.perf_counter()
            transport.sendto(payload)
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(0.2):
                    while client.received == before:
                        await client.event.wait()
                        client.event.clear()
                    rtts.append(time.perf_counter() - t0)
        await asyncio.sleep(0.01)  # let a late echo land before counting restarts
    # throughput: a window of packets in flight
    client.received = 0
    sent = 0
    lost_wait = 0
    t0 = time.perf_counter()
    deadline = loop.time() + TIME_LIMIT_S
    while client.received < packets and loop.time() < deadline:
        while sent < packets and sent - client.received < window:
            transport.sendto(payload)
            sent += 1
        client.event.clear()
        try:
            async with asyncio.timeout(0.05):
                await client.event.wait()
        except TimeoutError:  # a datagram was lost: refill the window
            lost_wait += 1
            sent = client.received
    elapsed = time.perf_counter() - t0
    one_way_ms = sorted(r * 1e3 / 2 for r in rtts)
    return {
        "packets": client.received,
        "elapsed_s": elapsed,
        "packets_per_s": client.received / elapsed,
        "mbit_per_s": client.received * size * 8 / elapsed / 1e6,
        "window_stalls": lost_wait,
        "one_way_ms_median": statistics.median(one_way_ms),
        "one_way_ms_p99": one_way_ms[min(len(one_way_ms) - 1, int(0.99 * len(one_way_ms)))],
        "pings_lost": pings - len(rtts),
    }


def _relay_process(echo_addr: tuple[str, int], seed: int, ports: Any, stop: Any) -> None:
    """Child process: run the relay until ``stop`` is set (bounded by TIME_LIMIT_S * 8)."""

    async def serve() -> None:
        relay = Relay(get_profile("ideal"), seed)
        try:
            listen = await relay.start_udp((LO, 0), echo_addr)
            ports.put(listen)
            loop = asyncio.get_running_loop()
            deadline = loop.time() + TIME_LIMIT_S * 8
            while not stop.is_set() and loop.time() < deadline:
                await asyncio.sleep(0.05)
            ports.put(dataclasses.asdict(relay.stats()))
        finally:
            await relay.close()

    asyncio.run(serve())


async def run(packets: int, size: int, window: int, pings: int, seed: int,
              repeats: int) -> dict[str, Any]:
    loop = asyncio.get_running_loop()
    echo_t, _ = await loop.create_datagram_endpoint(_Echo, local_addr=(LO, 0))
    echo_addr = echo_t.get_extra_info("sockname")[:2]
    ctx = multiprocessing.get_context("spawn")
    ports, stop = ctx.Queue(), ctx.Event()
    proc = ctx.Process(target=_relay_process, args=(echo_addr, seed, ports, stop), daemon=True)
    proc.start()
    runs: dict[str, list[dict[str, Any]]] = {"direct": [], "relay": []}
    targets: dict[str, tuple[asyncio.DatagramTransport, _Client]] = {}
    try:
        listen = await loop.run_in_executor(None, ports.get, True, TIME_LIMIT_S)
        # one client socket per path: the relay learns its client from the first datagram
        targets = {}
        for name, addr in (("direct", echo_addr), ("relay", tuple(listen))):
            targets[name] = await loop.create_datagram_endpoint(_Client, remote_addr=addr)
        for name, target in targets.items():  # warm-up, not recorded
            await _measure(target, min(2000, packets), size, window, min(100, pings))
        for _ in range(repeats):  # alternate so drift hits both paths alike
            for name, target in targets.items():
                runs[name].append(await _measure(target, packets, size, window, pings))
        stop.set()
        counters = await loop.run_in_executor(None, ports.get, True, TIME_LIMIT_S)
    finally:
        stop.set()
        for transport, _ in targets.values():
            transport.close()
        proc.join(5)
        if proc.is_alive():
            proc.terminate()
        echo_t.close()

    def median_run(name: str) -> dict[str, Any]:
        out = {k: statistics.median(r[k] for r in runs[name]) for k in runs[name][0]}
        out["repeats"] = len(runs[name])
        return out

    direct, relayed = median_run("direct"), median_run("relay")
    return {
        "benchmark": "bench_relay",
        "profile": "ideal",
        "setup": "client + UDP echo server in one process; relay in a second process",
        "params": {"packets": packets, "size_bytes": size, "window": window, "pings": pings,
                   "seed": seed, "repeats": repeats},
        "direct": direct,
        "relay": relayed,
        "runs": runs,
        "relay_counters": counters,
        "ratio_throughput_relay_over_direct": relayed["packets_per_s"] / direct["packets_per_s"],
        "added_one_way_ms_median": relayed["one_way_ms_median"] - direct["one_way_ms_median"],
        "env": {"python": sys.version.split()[0], "platform": platform.platform(),
                "machine": platform.machine(), "cpus": os.cpu_count()},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--packets", type=int, default=20_000)
    parser.add_argument("--size", type=int, default=1200, help="UDP payload bytes")
    parser.add_argument("--window", type=int, default=64, help="datagrams in flight")
    parser.add_argument("--pings", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=3, help="alternating runs per path")
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).resolve().parent / "results" / "bench_relay.json")
    ns = parser.parse_args(argv)
    result = asyncio.run(run(ns.packets, ns.size, ns.window, ns.pings, ns.seed, ns.repeats))
    ns.out.parent.mkdir(parents=True, exist_ok=True)
    ns.out.write_text(json.dumps(result, indent=2) + "\n")
    d, r = result["direct"], result["relay"]
    print(f"direct: {d['packets_per_s']:.0f} pkt/s {d['mbit_per_s']:.1f} Mbit/s "
          f"one-way {d['one_way_ms_median']:.3f} ms")
    print(f"relay : {r['packets_per_s']:.0f} pkt/s {r['mbit_per_s']:.1f} Mbit/s "
          f"one-way {r['one_way_ms_median']:.3f} ms")
    print(f"ratio {result['ratio_throughput_relay_over_direct']:.2f}, added one-way "
          f"{result['added_one_way_ms_median']:.3f} ms -> {ns.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
