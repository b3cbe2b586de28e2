"""Session options declared once (issue 47): every option reaches the core from each front door under one flag and
one range, and the documentation's table is the declaration's."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from splitrender.cli import build_parser
from splitrender.client.cli import config_from_args as client_config
from splitrender.client.session import ClientConfig
from splitrender.errors import ConfigError
from splitrender.options import ClientOptions, ServerProtocolOptions, declared, options_table
from splitrender.pipeline import ServerOptions
from splitrender.server.cli import config_from_args as serve_config
from splitrender.server.server import ServerConfig
from splitrender.sim.config import RunConfig, session_options

CLIENT = list(declared(ClientOptions))
SERVER = list(declared(ServerProtocolOptions))


def _inside(f: dataclasses.Field, o) -> float:
    """A value in range that is not the default (so it can only arrive by being passed)."""
    v = o.lo + (o.hi - o.lo) / 3
    return int(v) if f.type in ("int", int) else round(v, 3)


def _run_config(argv: list[str]) -> RunConfig:
    ns = build_parser().parse_args(["run", *argv])
    return RunConfig.from_dict(session_options(ns))


@pytest.mark.parametrize("f,o", CLIENT + SERVER, ids=[f.name for f, _ in CLIENT + SERVER])
def test_every_option_reaches_the_core_from_every_front_door(f, o):
    value = _inside(f, o)
    assert value != f.default
    flag = [o.flag, str(value)]
    client_side = (f, o) in CLIENT
    # virtual time: run takes both sides, under the same flag
    run = _run_config(flag)
    core = run.client_options() if client_side else run.server_options()
    assert getattr(core, f.name) == value
    # live: client or serve takes its side
    if client_side:
        ns = build_parser().parse_args(["client", *flag])
        assert getattr(client_config(ns).options(), f.name) == value
        assert getattr(ClientConfig(**{f.name: value}).options(), f.name) == value
    else:
        ns = build_parser().parse_args(["serve", *flag])
        assert getattr(serve_config(ns).session_options(), f.name) == value
        assert getattr(ServerConfig(**{f.name: value}).session_options(), f.name) == value
    # and as a config (TOML) key, under its name (and its old name where RunConfig had one)
    for key in (f.name, *([o.old_key] if o.old_key else [])):
        assert getattr(RunConfig.from_dict({key: value}), f.name) == value


@pytest.mark.parametrize("end", ["above", "below"])
@pytest.mark.parametrize("f,o", CLIENT + SERVER, ids=[f.name for f, _ in CLIENT + SERVER])
def test_an_option_out_of_range_names_its_flag_and_one_range_everywhere(f, o, end):
    bad = o.hi * 2 + 1 if end == "above" else o.lo - 1
    bad = int(bad) if f.type in ("int", int) else bad
    side = "client" if (f, o) in CLIENT else "serve"
    messages = []
    for cmd in ("run", side):
        ns = build_parser().parse_args([cmd, f"{o.flag}={bad}"])   # "=": a negative value is not read as a flag
        with pytest.raises(ConfigError) as err:
            session_options(ns) if cmd == "run" else (client_config(ns) if side == "client" else serve_config(ns))
        messages.append(str(err.value))
    assert messages[0] == messages[1]
    assert messages[0].startswith(f"{o.flag}: must be in [") and f"got {bad}" in messages[0]
    # the cores and the configs refuse it with the same range, by the option's name
    with pytest.raises(ConfigError, match=rf"{f.name}: must be in \[.*\].*got {bad}"):
        (ClientOptions if side == "client" else ServerOptions)(**{f.name: bad})
    with pytest.raises(ConfigError, match=f.name):
        RunConfig.from_dict({o.old_key or f.name: bad})


def test_virtual_time_defaults_differ_only_where_declared():
    run, client, server = RunConfig(), ClientConfig(), ServerConfig()
    assert run.client_options() == dataclasses.replace(client.options(), jitter_timeout_ms=100.0,
                                                       stall_timeout_s=math.inf, limits=run.client_options().limits)
    assert run.server_options() == server.session_options()
    assert ClientOptions(stall_timeout_s=math.inf).stall_timeout_s == math.inf   # "never" is allowed


def test_stored_run_keys_are_unchanged_by_the_declaration():
    """Results stores are keyed on RunConfig.key(): the options that were fields before keep hashing as they did
    (these values were computed by the code before the options were declared once, 2026-12-06), and an option
    added since changes a key only when it differs from its default."""
    assert RunConfig().key() == "9bd4aaccdc3cc6e2"
    assert RunConfig(nack_max_tries=2, history_packets=100, method="sas").key() == "20b3f3405666b18b"
    assert RunConfig(nack_delay_ms=20.0).key() == RunConfig().key() != RunConfig(nack_delay_ms=30.0).key()
    # the two options RunConfig once named otherwise hash under those names (nack_tries,
    # keyframe_request_interval_ms), and a stored config.toml's old names read as the live ones
    assert RunConfig(pli_interval_ms=100.0).key() == "53cd28c04f6435a3"
    old = RunConfig.from_dict({"nack_tries": 2, "keyframe_request_interval_ms": 100.0})
    assert old == RunConfig(nack_max_tries=2, pli_interval_ms=100.0)
    with pytest.raises(ConfigError, match="'nack_tries' is the old name of 'nack_max_tries'"):
        RunConfig.from_dict({"nack_tries": 2, "nack_max_tries": 2})


def test_the_protocol_docs_table_is_the_declaration():
    doc = (Path(__file__).resolve().parents[1] / "docs" / "protocol.md").read_text()
    assert options_table() in doc


@pytest.mark.parametrize("f,o", [(f, o) for f, o in CLIENT + SERVER if f.type in ("int", int)],
                         ids=[f.name for f, _ in CLIENT + SERVER if f.type in ("int", int)])
def test_an_integer_option_refuses_a_fraction_or_a_bool(f, o):
    side, cls = ("client", ClientOptions) if (f, o) in CLIENT else ("server", ServerOptions)
    for bad in (2.5, True):
        with pytest.raises(ConfigError, match=rf"^{side} {f.name}: must be an integer, got {bad!r}$"):
            cls(**{f.name: bad})
