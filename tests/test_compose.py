"""docker-compose.yml and docker/Dockerfile: structure, commands, netem arguments.

There is no Docker engine here; these tests check the files statically, and that the
netem arguments are exactly what splitrender's own parser and profiles say.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from splitrender.netsim import get_profile, parse_netem, to_netem
from splitrender.netsim.cli import add_shape_arguments, resolve_path

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def compose() -> dict[str, Any]:
    data = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    assert isinstance(data, dict)
    return data


def _argv(command: Any) -> list[str]:
    return command if isinstance(command, list) else str(command).split()


def test_services_and_build(compose: dict[str, Any]) -> None:
    services = compose["services"]
    assert {"server", "client", "netem-server", "netem-client", "relay"} <= set(services)
    for name, svc in services.items():
        assert svc["build"]["dockerfile"] == "docker/Dockerfile", name
        assert svc["build"]["context"] == "."
        assert svc["image"] == "splitrender:latest"
    assert (ROOT / services["server"]["build"]["dockerfile"]).is_file()


def test_server_and_client_commands(compose: dict[str, Any]) -> None:
    server = _argv(compose["services"]["server"]["command"])
    client = _argv(compose["services"]["client"]["command"])
    assert server[:2] == ["splitrender", "serve"]
    assert server[server.index("--host") + 1] == "0.0.0.0"
    assert client[:2] == ["splitrender", "client"]
    assert client[client.index("--server") + 1] == "server"
    assert client[client.index("--port") + 1] == server[server.index("--port") + 1]
    assert "server" in compose["services"]["client"]["depends_on"]
    # the client records into the folder the host mounts (not the container's out/live)
    mounts = {v.split(":")[1]: v.split(":")[0] for v in compose["services"]["client"]["volumes"]}
    assert mounts.get(client[client.index("--out") + 1]) == "./results", (client, mounts)
    # the unshaped setup runs without any profile
    for name in ("server", "client"):
        assert "profiles" not in compose["services"][name]


def _netem_args(svc: dict[str, Any]) -> str:
    script = " ".join(_argv(svc["command"]))
    m = re.search(r"tc qdisc (?:add|replace) dev eth0 root netem (.*?)(?:&&|;|$)", script)
    assert m is not None, script
    return m.group(1).strip()


@pytest.mark.parametrize(("name", "target", "direction"),
                         [("netem-server", "server", "downlink"), ("netem-client", "client", "uplink")])
def test_netem_sidecars(compose: dict[str, Any], name: str, target: str, direction: str) -> None:
    svc = compose["services"][name]
    assert svc["cap_add"] == ["NET_ADMIN"]
    assert svc["network_mode"] == f"service:{target}"
    assert svc["profiles"] == ["netem"]
    args = _netem_args(svc)
    expected = getattr(get_profile("cloud"), direction)
    assert parse_netem(args) == expected
    assert args == to_netem(expected)


def test_relay_service_parses_with_shape_cli(compose: dict[str, Any]) -> None:
    argv = _argv(compose["services"]["relay"]["command"])
    assert argv[:2] == ["splitrender", "shape"]
    ns = add_shape_arguments(argparse.ArgumentParser()).parse_args(argv[2:])
    assert ns.allow_remote and ns.to_tcp == ("server", 9100)
    assert resolve_path(ns) == get_profile("cloud")


def test_dockerfile_installs_egl_and_tc() -> None:
    text = (ROOT / "docker" / "Dockerfile").read_text()
    assert re.search(r"^FROM python:3\.11-slim\b", text, re.M)
    apt = re.search(r"apt-get install(?:[^\n\\]|\\\n)*", text)  # with continuation lines
    assert apt is not None
    for pkg in ("libegl1", "libegl-mesa0", "libgl1-mesa-dri", "iproute2"):
        assert re.search(rf"(?<![\w-]){re.escape(pkg)}(?![\w-])", apt.group(0)), pkg
    assert re.search(r"^RUN pip install \.\s*$", text, re.M)
    assert "COPY splitrender" in text


def test_browser_front_door_service(compose: dict[str, Any]) -> None:
    """The ``browser`` profile serves the page on the host's port 8080 with host networking (WebRTC's ephemeral
    media ports), its recordings into the mounted results folder; its command parses as ``splitrender serve``."""
    from splitrender.cli import build_parser
    from splitrender.server.cli import config_from_args

    svc = compose["services"]["browser"]
    assert svc["profiles"] == ["browser"] and svc["network_mode"] == "host"
    argv = _argv(svc["command"])
    assert argv[:2] == ["splitrender", "serve"]
    cfg = config_from_args(build_parser().parse_args(argv[1:]))
    assert cfg.webrtc_http == ("0.0.0.0", 8080) and cfg.host == "0.0.0.0"
    mounts = {v.split(":")[1]: v.split(":")[0] for v in svc["volumes"]}
    assert str(cfg.out_dir).startswith("/results") and mounts["/results"] == "./results"
    # not the unshaped set-up's ports: both may run on one host
    server = _argv(compose["services"]["server"]["command"])
    assert cfg.port != int(server[server.index("--port") + 1])
