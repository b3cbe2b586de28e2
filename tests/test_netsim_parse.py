"""netem strings, dict/TOML form, parse_path: round trips, exact errors, fuzzing."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.errors import NetworkConfigError
from splitrender.netsim import (
    GilbertElliott,
    LinkSpec,
    PathSpec,
    get_profile,
    parse_netem,
    parse_path,
    to_netem,
)


def test_brief_example() -> None:
    spec = parse_netem(
        "delay 50ms 20ms distribution uniform loss gemodel 1% 30% rate 20mbit limit 1000"
    )
    assert spec == LinkSpec(
        delay_ms=50, jitter_ms=20, gemodel=GilbertElliott(1, 30), rate_bps=20e6,
        limit_packets=1000,
    )
    assert to_netem(spec) == "delay 50ms 20ms loss gemodel 1% 30% 100% 0% rate 20mbit"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", LinkSpec()),
        ("netem delay 5ms", LinkSpec(delay_ms=5)),
        ("loss 1%", LinkSpec(loss_pct=1)),
        ("loss random 1%", LinkSpec(loss_pct=1)),
        ("loss 1% 25%", LinkSpec(loss_pct=1, loss_correlation_pct=25)),
        ("duplicate 1%", LinkSpec(duplicate_pct=1)),
        ("corrupt 0.1%", LinkSpec(corrupt_pct=0.1)),
        ("delay 10ms reorder 25% 50% gap 5",
         LinkSpec(delay_ms=10, reorder_pct=25, reorder_correlation_pct=50, reorder_gap=5)),
        ("delay 10ms reorder 25% gap 5", LinkSpec(delay_ms=10, reorder_pct=25, reorder_gap=5)),
        ("delay 1s 500us 10%", LinkSpec(delay_ms=1000, jitter_ms=0.5, delay_correlation_pct=10)),
        ("delay 100ms 10ms distribution pareto",
         LinkSpec(delay_ms=100, jitter_ms=10, distribution="pareto")),
        ("loss gemodel 1%", LinkSpec(gemodel=GilbertElliott(1))),
        ("loss gemodel 1% 10% 70% 0.1%", LinkSpec(gemodel=GilbertElliott(1, 10, 70, 0.1))),
        ("rate 1500bit", LinkSpec(rate_bps=1500)),
        ("rate 2kbit", LinkSpec(rate_bps=2000)),
        ("rate 1.5gbit", LinkSpec(rate_bps=1.5e9)),
        ("rate 100bps", LinkSpec(rate_bps=800)),  # tc: bps = bytes per second
        ("rate 1kbps", LinkSpec(rate_bps=8000)),
        ("rate 2mbps", LinkSpec(rate_bps=16e6)),
        ("rate 10Mbit limit 50", LinkSpec(rate_bps=10e6, limit_packets=50)),
        ("trace /x/y.mahi", LinkSpec(trace_path="/x/y.mahi")),
    ],
)
def test_parse_examples(text: str, expected: LinkSpec) -> None:
    assert parse_netem(text) == expected


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("delay fast", "netem: 'fast' is not a time (expected e.g. 20ms) at token 2"),
        ("delay 50", "netem: '50' is not a time (expected e.g. 20ms) at token 2"),
        ("delay", "netem: missing time after 'delay' at token 2"),
        ("delay 5ms 2ms distribution", "netem: missing distribution name after 'distribution' at token 5"),
        ("delay 5ms 2ms distribution cauchy",
         "netem: 'cauchy' is not a distribution (expected one of: normal, pareto, "
         "paretonormal, uniform) at token 5"),
        ("loss 1", "netem: '1' is not a percentage (expected e.g. 1%) at token 2"),
        ("loss 101%", "netem: '101%' is out of range 0..100% at token 2"),
        ("loss state 1%", "netem: 'loss state' (4-state Markov) is not supported; use gemodel at token 2"),
        ("rate fast", "netem: 'fast' is not a rate (expected e.g. 20mbit) at token 2"),
        ("rate 0mbit", "netem: '0mbit' is not a positive rate at token 2"),
        ("limit -3", "netem: '-3' is not a packet count (expected e.g. 1000) at token 2"),
        ("delay 1ms jitter", "netem: unknown keyword 'jitter' (expected one of: corrupt, delay, "
         "distribution, duplicate, gap, limit, loss, rate, reorder, spike, trace) at token 3"),
        ("delay 1ms delay 2ms", "netem: 'delay' given twice at token 3"),
        ("reorder 5%", "netem: reorder_pct needs delay_ms > 0 (as in netem)"),
        ("delay 1e999ms", "netem: '1e999ms' is out of range at token 2"),
        ("delay 1_0ms", "netem: '1_0ms' is not a time (expected e.g. 20ms) at token 2"),
        ("delay nanms", "netem: 'nanms' is not a time (expected e.g. 20ms) at token 2"),
        ("trace", "netem: missing trace file after 'trace' at token 2"),
    ],
)
def test_exact_error_texts(text: str, message: str) -> None:
    with pytest.raises(NetworkConfigError) as exc:
        parse_netem(text)
    assert str(exc.value) == message


def test_profiles_render_for_tc() -> None:
    assert to_netem(get_profile("cloud").downlink) == "delay 50ms 20ms"
    assert to_netem(get_profile("lan").uplink) == "delay 20ms 10ms"
    assert to_netem(get_profile("ideal").uplink) == ""
    assert "uniform" not in to_netem(LinkSpec(delay_ms=1, jitter_ms=1))  # tc has no such table
    for name in ("wifi", "lte"):
        for link in (get_profile(name).uplink, get_profile(name).downlink):
            assert parse_netem(to_netem(link)) == link
    with pytest.raises(NetworkConfigError, match="cannot be expressed for tc"):
        to_netem(LinkSpec(trace_path="x"))


pct = st.floats(0, 100, allow_nan=False).map(lambda x: round(x, 3))


@st.composite
def link_specs(draw: st.DrawFn) -> LinkSpec:
    jitter = draw(st.one_of(st.just(0.0), st.floats(0.001, 1e4)))
    delay = draw(st.one_of(st.just(0.0), st.floats(0.001, 1e5)))
    dist = draw(st.sampled_from(["uniform", "normal", "pareto", "paretonormal"])) if jitter else "uniform"
    use_ge = draw(st.booleans())
    reorder = draw(pct) if delay > 0 else 0.0
    return LinkSpec(
        delay_ms=delay,
        jitter_ms=jitter,
        delay_correlation_pct=draw(pct),
        distribution=dist,
        loss_pct=0.0 if use_ge else draw(pct),
        loss_correlation_pct=0.0 if use_ge else draw(pct),
        gemodel=GilbertElliott(draw(pct), draw(pct), draw(pct), draw(pct)) if use_ge else None,
        duplicate_pct=draw(pct),
        duplicate_correlation_pct=draw(pct),
        corrupt_pct=draw(pct),
        corrupt_correlation_pct=draw(pct),
        reorder_pct=reorder,
        reorder_correlation_pct=draw(pct),
        reorder_gap=draw(st.integers(1, 100)),
        rate_bps=draw(st.one_of(st.none(), st.floats(1, 1e11), st.integers(1, 10**11).map(float))),
        limit_packets=draw(st.integers(1, 10**6)),
    )


@settings(max_examples=300, deadline=None)
@given(link_specs())
def test_round_trip(spec: LinkSpec) -> None:
    assert parse_netem(to_netem(spec)) == spec


@settings(max_examples=300, deadline=None)
@given(link_specs())
def test_dict_round_trip(spec: LinkSpec) -> None:
    path = PathSpec(uplink=spec)
    assert PathSpec.from_dict(path.to_dict()) == path


_WORDS = ["delay", "loss", "random", "gemodel", "state", "rate", "limit", "reorder", "gap",
          "duplicate", "corrupt", "distribution", "normal", "uniform", "trace", "netem",
          "10ms", "5%", "1e3us", "20mbit", "7", "-1", "0", "x", "150%", ".5s", "1e999ms"]


@settings(max_examples=500, deadline=None)
@given(st.one_of(st.text(max_size=60), st.lists(st.sampled_from(_WORDS), max_size=12).map(" ".join)))
def test_fuzz_parses_or_raises_network_config_error(text: str) -> None:
    for parse in (parse_netem, parse_path):
        try:
            parse(text)
        except NetworkConfigError:
            pass


# -- parse_path -------------------------------------------------------------------------


def test_parse_path_forms() -> None:
    assert parse_path("cloud") == get_profile("cloud")
    assert parse_path(" lan ") == get_profile("lan")
    assert parse_path("delay 5ms loss 1%") == PathSpec.symmetric(LinkSpec(delay_ms=5, loss_pct=1))
    p = parse_path("up: delay 5ms; down: rate 10mbit")
    assert p == PathSpec(uplink=LinkSpec(delay_ms=5), downlink=LinkSpec(rate_bps=10e6))
    assert parse_path("down: lte").downlink == get_profile("lte").downlink
    assert parse_path("down: lte").uplink == LinkSpec()
    with pytest.raises(NetworkConfigError) as exc:
        parse_path("up: delay 5ms; sideways: x")
    assert str(exc.value) == "network path: 'sideways: x' does not start with 'up:' or 'down:'"
    with pytest.raises(NetworkConfigError) as exc:
        parse_path("up: delay fast")
    assert str(exc.value) == "uplink: netem: 'fast' is not a time (expected e.g. 20ms) at token 2"
    with pytest.raises(NetworkConfigError, match="downlink given twice"):
        parse_path("down: lan; down: cloud")


# -- dict / TOML ------------------------------------------------------------------------


def test_from_dict() -> None:
    p = PathSpec.from_dict({
        "uplink": {"delay_ms": 10, "loss_pct": 1.5},
        "downlink": {"delay_ms": 50, "jitter_ms": 20, "rate_bps": 2e7, "keep_order": False,
                     "gemodel": {"p_pct": 1, "r_pct": 30}},
    })
    assert p.uplink == LinkSpec(delay_ms=10, loss_pct=1.5)
    assert p.downlink.gemodel == GilbertElliott(1, 30) and p.downlink.keep_order is False


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"sidelink": {}}, "network path: unknown key 'sidelink' (valid: downlink, uplink)"),
        ({"uplink": {"delay": 5}}, "uplink: unknown key 'delay' (valid: corrupt_correlation_pct,"),
        ({"downlink": {"delay_ms": -5}}, "downlink.delay_ms must be >= 0, got -5"),
        ({"downlink": {"jitter_ms": "5ms"}}, "downlink.jitter_ms must be a number, got '5ms'"),
        ({"downlink": {"limit_packets": 2.5}}, "downlink.limit_packets must be an integer, got 2.5"),
        ({"downlink": {"keep_order": 1}}, "downlink.keep_order must be true or false, got 1"),
        ({"uplink": {"gemodel": {"p_pct": 1, "q": 2}}}, "uplink.gemodel: unknown key 'q'"),
        ({"uplink": {"gemodel": {"r_pct": 2}}}, "uplink.gemodel: missing key 'p_pct'"),
        ({"uplink": {"gemodel": {"p_pct": -2}}}, "uplink.gemodel.p_pct must be within 0..100"),
        ({"uplink": []}, "uplink must be a table/dict, got list"),
    ],
)
def test_from_dict_errors(data: dict, message: str) -> None:
    with pytest.raises(NetworkConfigError) as exc:
        PathSpec.from_dict(data)
    assert str(exc.value).startswith(message)


def test_from_toml(tmp_path: Path) -> None:
    f = tmp_path / "net.toml"
    f.write_text(
        "[network.uplink]\ndelay_ms = 20\njitter_ms = 10\n"
        "[network.downlink]\ndelay_ms = 50\njitter_ms = 20\n"
    )
    assert PathSpec.from_toml(f, "network") == get_profile("lan").__class__(
        uplink=get_profile("lan").uplink, downlink=get_profile("cloud").downlink
    )
    bad = tmp_path / "bad.toml"
    bad.write_text("[uplink]\nloss_pct = -1\n")
    with pytest.raises(NetworkConfigError) as exc:
        PathSpec.from_toml(bad)
    assert str(exc.value) == f"{str(bad)!r}: uplink.loss_pct must be within 0..100 (percent), got -1"
    with pytest.raises(NetworkConfigError, match=r"no table \[net\]"):
        PathSpec.from_toml(f, "net")
