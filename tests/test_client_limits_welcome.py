"""What a Welcome makes a client hold is held to its ``ClientLimits`` before anything is allocated (issue 46,
finding 3), and the client's handshake waits end in errors that say what was awaited, from where, for how long
(finding 8).

A method's config sizes client memory (warp's reference image and mesh, atw's overscanned frame, the sas, tss and
quads atlases, the split scenes sas and tss hold): each config says what it makes a client of a display hold
(``MethodConfig.client_sizes``), the handshake checks it when it takes the Welcome, and the client half checks it
again before it allocates.  Before the fix, the warp Welcome ``fov_scale=6, resolution_scale=4,
reconstruction="mesh"`` made a 160x90 client build 190 MiB of mesh indices (570 MiB at the peak, measured with
tracemalloc)."""

from __future__ import annotations

import asyncio
import dataclasses
import re
import tomllib
import tracemalloc
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.errors import PeerTimeoutError
from splitrender.limits import DEFAULT_CLIENT_LIMITS, ClientLimitError, ClientLimits
from splitrender.methods.base import get_method, make_config
from splitrender.pipeline import ClientHandshake
from splitrender.protocol import ServerConnection, Welcome
from splitrender.scene.pose import CameraIntrinsics

METHODS = ("video", "atw", "warp", "sas", "tss", "quads", "probes")
SMALL = (160, 90)


def welcome(method: str, config: dict[str, Any], **params: Any) -> Welcome:
    return Welcome("s", method, {"config": config, "fov_y_deg": 60.0, "server_fps": 30, **params}, ())


def take(method: str, config: dict[str, Any], display: tuple[int, int] = SMALL,
         limits: ClientLimits = DEFAULT_CLIENT_LIMITS) -> ClientHandshake:
    hs = ClientHandshake((method,), limits, display)
    assert hs.receive_message(welcome(method, config))     # no session data announced: done at the Welcome
    return hs


# ----------------------------------------------------------------------------- finding 3: oversized configs
REFUSED = [
    # (method, config, display, field, the rest of the message)
    ("warp", {"fov_scale": 6, "resolution_scale": 4, "reconstruction": "mesh"}, SMALL, "reconstruction",
     "the warp mesh (reconstruction 'mesh') over the reference image 3840x2160 (fov_scale 6 x resolution_scale 4 at a "
     "160x90 display) is 8.3 M vertices, over this client's limit max_mesh_vertices 4194304"),
    ("warp", {"fov_scale": 6, "resolution_scale": 4}, (1280, 720), "resolution_scale",
     "the warp reference image 30720x17280 (fov_scale 6 x resolution_scale 4 at a 1280x720 display) is 530.8 M pixels, "
     "over this client's limit max_reference_pixels 16777216"),
    ("warp", {"fov_scale": 6}, (1280, 720), "fov_scale",
     "the warp reference image 7680x4320 (fov_scale 6 x resolution_scale 1 at a 1280x720 display) is 33.2 M pixels, "
     "over this client's limit max_reference_pixels 16777216"),
    ("warp", {"fov_scale": 3.2, "views": 2}, (1280, 720), "views",
     "2 warp reference views of 4096x2304 (fov_scale 3.2 x resolution_scale 1 at a 1280x720 display) is 18.9 M pixels, "
     "over this client's limit max_reference_pixels 16777216"),
    ("atw", {"overscan": 3.0}, (1920, 1080), "overscan",
     "the atw frame 5760x3240 (overscan 3 at a 1920x1080 display) is 18.7 M pixels, over this client's limit "
     "max_reference_pixels 16777216"),
    ("sas", {"atlas_mpix_1080p": 1e4}, SMALL, "atlas_mpix_1080p",
     "the sas atlas 11776x5888 (atlas_mpix_1080p 10000 at a 160x90 display) is 69.3 M texels, over this client's "
     "limit max_atlas_pixels 16777216"),
    ("sas", {"atlas_mpix_1080p": 1e300}, SMALL, "atlas_mpix_1080p",
     "the sas atlas (atlas_mpix_1080p 1e+300 at a 160x90 display) is 1152921504606.8 M texels, over this client's "
     "limit max_atlas_pixels 16777216"),
    ("sas", {"atlas_width": 8192, "atlas_height": 4096}, SMALL, "atlas_width",
     "the sas atlas 8192x4096 (atlas_width x atlas_height) is 33.6 M texels, over this client's limit "
     "max_atlas_pixels 16777216"),
    ("sas", {"split_max_triangles": 50_000_000}, SMALL, "split_max_triangles",
     "the split scene whose patches the sas client may hold is 50.0 M triangles, over this client's limit "
     "max_scene_triangles 4000000"),
    ("tss", {"atlas_mpix_1080p": 64}, (1920, 1080), "atlas_mpix_1080p",
     "the tss atlas 11328x5664 (atlas_mpix_1080p 64 at a 1920x1080 display) is 64.2 M texels, over this client's "
     "limit max_atlas_pixels 16777216"),
    ("tss", {"split_max_triangles": 50_000_000}, SMALL, "split_max_triangles",
     "the tessellated scene the tss client may hold is 50.0 M triangles, over this client's limit "
     "max_scene_triangles 4000000"),
    ("quads", {"variant": "quadstream", "atlas": "slots"}, (1920, 1080), "variant",
     "the quads atlas 9600x2160 (10 views of a 1920x1080 display: variant quadstream, layers 2, a wide view, "
     "atlas slots) is 20.7 M texels, over this client's limit max_atlas_pixels 16777216"),
    ("quads", {"layers": 4}, (2560, 1440), "layers",
     "the quads atlas 7680x2880 (6 views of a 2560x1440 display: variant quasar, layers 4, a wide view, atlas slots) "
     "is 22.1 M texels, over this client's limit max_atlas_pixels 16777216"),
]


@pytest.mark.parametrize(("method", "config", "display", "field", "text"), REFUSED,
                         ids=[f"{m}-{f}" for m, _, _, f, _ in REFUSED])
def test_a_welcome_sizing_more_than_the_limits_is_refused_naming_the_field(method: str, config: dict[str, Any],
                                                                          display: tuple[int, int], field: str,
                                                                          text: str) -> None:
    hs = ClientHandshake((method,), DEFAULT_CLIENT_LIMITS, display)
    with pytest.raises(ClientLimitError) as err:
        hs.receive_message(welcome(method, config))
    assert str(err.value) == f"Welcome.method_params.config.{field}: {text}"
    assert err.value.code == 413 and hs.terms is None and hs.welcome is None


def test_the_warp_welcome_of_the_finding_is_refused_before_any_allocation() -> None:
    """The finding's Welcome at a 160x90 display: refused by the handshake allocating well under a MB (it cost
    570 MiB at the peak before), and by the client half too, for a half built without the handshake (as the
    studies do): its base class checks before the half allocates anything, so no GL context is needed to see it."""
    cfg = {"fov_scale": 6, "resolution_scale": 4, "reconstruction": "mesh"}
    spec = get_method("warp")
    spec.client_class                                       # imports done before the measurement
    with pytest.raises(ClientLimitError):
        ClientHandshake(("warp",), DEFAULT_CLIENT_LIMITS, SMALL).receive_message(welcome("warp", cfg))
    tracemalloc.start()
    try:
        with pytest.raises(ClientLimitError, match=r"^Welcome.method_params.config.reconstruction: "):
            ClientHandshake(("warp",), DEFAULT_CLIENT_LIMITS, SMALL).receive_message(welcome("warp", cfg))
        with pytest.raises(ClientLimitError, match=r"^WarpConfig.reconstruction: the warp mesh .* is 8.3 M vertices"):
            spec.client_class(make_config(spec.config, cfg), CameraIntrinsics(*SMALL), None, {})
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20, f"the refusals allocated {peak / 2**20:.1f} MiB at the peak"


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("display", [SMALL, (640, 360), (1280, 720)])
def test_a_default_configured_welcome_of_every_method_is_accepted(method: str, display: tuple[int, int]) -> None:
    hs = take(method, {}, display)
    assert hs.terms is not None and hs.terms.config == make_config(get_method(method).config, {})


# every configuration of a method's knobs the project's tests, demos, studies and benchmarks run, at their sizes
USED = [
    ("warp", {"reconstruction": "mesh", "fov_scale": 3.0, "resolution_scale": 2.0 / 3.0, "depth_coding": "bc4"}, (640, 360)),
    ("warp", {"reconstruction": "mesh", "fov_scale": 1.0}, (640, 360)),
    ("warp", {"reconstruction": "quads", "fov_scale": 3.0, "resolution_scale": 0.5}, (640, 360)),
    ("warp", {"views": 2, "reconstruction": "mesh"}, (640, 360)),
    ("warp", {}, (3840, 2160)),                              # the default at 4K: 4992x2808
    ("atw", {"overscan": 1.5}, (640, 360)),
    ("atw", {}, (3840, 2160)),
    ("sas", {"atlas_mpix_1080p": 24.0}, (640, 360)),
    ("sas", {"atlas_width": 192, "atlas_height": 96}, (320, 180)),
    ("sas", {}, (1920, 1080)),
    ("tss", {"atlas_mpix_1080p": 64}, (640, 360)),
    ("tss", {}, (1280, 720)),
    ("quads", {"variant": "quadstream"}, (1280, 720)),
    ("quads", {"layers": 4}, (1920, 1080)),
    ("quads", {}, (1920, 1080)),
]


@pytest.mark.parametrize(("method", "config", "display"), USED)
def test_the_configurations_the_project_runs_are_accepted(method: str, config: dict[str, Any],
                                                           display: tuple[int, int]) -> None:
    take(method, config, display)


def test_the_check_names_the_limit_a_client_lowered_and_the_runner_checks_too() -> None:
    """A client that lowers a limit gets the refusal at that limit; the virtual-time runner hands its Hello's display
    to the same handshake."""
    low = dataclasses.replace(DEFAULT_CLIENT_LIMITS, max_reference_pixels=4 * 1024 * 1024)
    hs = ClientHandshake(("warp",), low, SMALL)
    with pytest.raises(ClientLimitError, match=re.escape(
            "Welcome.method_params.config.resolution_scale: the warp reference image 3840x2160 (fov_scale 6 x "
            "resolution_scale 4 at a 160x90 display) is 8.3 M pixels, over this client's limit max_reference_pixels "
            "4194304")):
        hs.receive_message(welcome("warp", {"fov_scale": 6, "resolution_scale": 4}))
    from splitrender.sim.config import RunConfig
    from splitrender.sim.runner import run

    bad = RunConfig(method="warp", width=160, height=90, duration_s=0.1, metrics=False,
                    method_params={"fov_scale": 6, "resolution_scale": 4, "reconstruction": "mesh"})
    with pytest.raises(ClientLimitError, match=r"^Welcome.method_params.config.reconstruction: "):
        run(bad)


def test_tss_session_data_declaring_more_triangles_than_the_limit_is_refused_before_allocation() -> None:
    from splitrender.methods.tss.wire import TssWireError

    from splitrender.methods.tss.wire import WIRE_VERSION

    spec = get_method("tss")
    sd = {"v": WIRE_VERSION, "atlas": [256, 128], "strip": 128, "os_grid": "paper", "n_objects": 1,
          "n_triangles": (1 << 25) - 1, "sky": [0.0, 0.0, 0.0], "tri_base": np.zeros(1, np.int64),
          "obj_box": np.array([[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]], np.float32)}
    tracemalloc.start()
    try:
        with pytest.raises(TssWireError, match=re.escape(
                "tss session data: n_triangles: 33554431 triangles, over this client's limit max_scene_triangles 4000000")):
            spec.client_class(make_config(spec.config, {}), CameraIntrinsics(*SMALL), None, sd)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 4 << 20


# ----------------------------------------------------------------------------- the limits table
NEW = {"max_reference_pixels": 1 << 22, "max_atlas_pixels": 1 << 23, "max_mesh_vertices": 123_456}


def test_the_new_limits_round_trip_through_a_limits_table_and_the_cli() -> None:
    text = "[limits]\n" + "".join(f"{k} = {v}\n" for k, v in {**DEFAULT_CLIENT_LIMITS.to_dict(), **NEW}.items())
    limits = ClientLimits.from_dict(tomllib.loads(text)["limits"])
    assert {k: getattr(limits, k) for k in NEW} == NEW
    assert ClientLimits.from_dict(limits.to_dict()) == limits
    assert DEFAULT_CLIENT_LIMITS.to_dict()["max_mesh_vertices"] == 2048 * 2048
    from splitrender.cli import build_parser
    from splitrender.client.cli import config_from_args

    ns = build_parser().parse_args(["client", *(a for k, v in NEW.items() for a in ("--limit", f"{k}={v}"))])
    assert config_from_args(ns).limits == dataclasses.replace(DEFAULT_CLIENT_LIMITS, **NEW)  # type: ignore[attr-defined]
    with pytest.raises(Exception, match="client limits: max_mesh_vertices must be a positive integer, got 0"):
        ClientLimits.from_dict({"max_mesh_vertices": 0})


# ----------------------------------------------------------------------------- fuzz: any config in range
def _configs(method: str) -> st.SearchStrategy[dict[str, Any]]:
    """Each method's client-memory knobs over the ranges its config declares (the rest at their defaults)."""
    f = st.floats
    if method == "warp":
        return st.fixed_dictionaries({"fov_scale": f(1.0, 6.0), "resolution_scale": f(0.1, 4.0), "views": st.sampled_from([1, 2]),
                                      "reconstruction": st.sampled_from(["points", "quads", "mesh"])})
    if method == "atw":
        return st.fixed_dictionaries({"overscan": f(1.0, 3.0)})
    if method == "sas":
        side = st.integers(1, 1 << 15).map(lambda k: 32 * k)
        return st.one_of(st.fixed_dictionaries({"atlas_mpix_1080p": f(1e-3, 1e6), "split_max_triangles": st.integers(1, 50_000_000)}),
                         st.fixed_dictionaries({"atlas_width": side, "atlas_height": side}))
    if method == "tss":
        return st.fixed_dictionaries({"atlas_mpix_1080p": f(1e-3, 64.0), "split_max_triangles": st.integers(1, 50_000_000)})
    if method == "quads":
        return st.fixed_dictionaries({"variant": st.sampled_from(["quasar", "quadstream"]), "layers": st.integers(1, 4),
                                      "wide_fov_deg": st.sampled_from([0.0, 120.0]), "wide_scale": f(0.1, 1.0),
                                      "reference_every": st.integers(1, 10)})
    return st.fixed_dictionaries({"crf": f(0.0, 51.0)})       # video, probes: nothing sizes client memory


@settings(max_examples=150)
@given(method=st.sampled_from(METHODS), data=st.data(), width=st.integers(1, 2048), height=st.integers(1, 1152),
       scale=st.sampled_from([1, 8, 64, 1024]))
def test_any_config_in_range_is_accepted_within_the_limits_or_refused_naming_a_field(method: str, data: st.DataObject,
                                                                                    width: int, height: int,
                                                                                    scale: int) -> None:
    config = data.draw(_configs(method))
    display = (2 * width, 2 * height)
    limits = ClientLimits(**{k: max(1, v // scale) for k, v in DEFAULT_CLIENT_LIMITS.to_dict().items()})
    spec = get_method(method)
    hs = ClientHandshake((method,), limits, display)
    try:
        hs.receive_message(welcome(method, config))
    except ClientLimitError as exc:
        m = re.match(r"Welcome\.method_params\.config\.(\w+): .* is [\d.]+( M)? \w+, over this client's limit (\w+) (\d+)$",
                     str(exc))
        assert m is not None, str(exc)
        assert m[1] in {x.name for x in dataclasses.fields(spec.config)}     # a default may be over a lowered limit
        assert int(m[4]) == getattr(limits, m[3])
        return
    assert hs.terms is not None
    for size in hs.terms.config.client_sizes(CameraIntrinsics(*display, hs.terms.fov_y_deg)):
        assert size.amount <= getattr(limits, size.limit)


def test_the_quads_atlas_the_client_checks_is_the_one_the_server_makes() -> None:
    """``QuadsConfig.atlas_wh`` (the client's check) against the server half's own arithmetic."""
    import itertools

    from splitrender.methods.quads.config import QuadsConfig
    from splitrender.methods.quads.packing import packed_size
    from splitrender.methods.quads.server import n_slots, slot_grid, wide_intrinsics

    for variant, layers, wide_fov, every, atlas, (w, h) in itertools.product(
            ["quasar", "quadstream"], [1, 2, 4], [0.0, 120.0], [1, 5], [None, "slots", "packed"], [(160, 90), (640, 360), (1920, 1080)]):
        if variant == "quasar" and atlas == "packed":
            continue
        c = QuadsConfig(variant=variant, layers=layers, wide_fov_deg=wide_fov, reference_every=every, atlas=atlas)
        i = CameraIntrinsics(w, h)
        cols, rows = slot_grid(n_slots(c))
        wide = wide_intrinsics(i, c.wide_fov_deg, c.wide_res) if c.wide_fov_deg else None
        views = [i] * (n_slots(c) - (1 if wide else 0)) + ([wide] if wide else [])
        packed = packed_size(w, h, sum(v.width * v.height for v in views), w * cols) if c.atlas_layout == "packed" else None
        assert c.atlas_wh(i) == (packed or (w * cols, h * rows)), c


# ----------------------------------------------------------------------------- finding 8: timeouts that say what
class _MuteServer:
    """A TCP server that takes the client's Hello and then answers with ``answer`` (bytes of messages) or nothing."""

    def __init__(self, answer: Welcome | None) -> None:
        self.answer = answer
        self.server: asyncio.Server | None = None
        self.errors: list[Any] = []
        self.handlers: set[asyncio.Task[Any]] = set()

    async def start(self) -> int:
        self.server = await asyncio.start_server(self._serve, "127.0.0.1", 0)
        return int(self.server.sockets[0].getsockname()[1])

    async def close(self) -> None:
        """Stop listening and wait for the connections' handlers (each ends at the client's EOF)."""
        assert self.server is not None
        self.server.close()
        await asyncio.wait_for(asyncio.gather(*self.handlers), 5.0)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self.handlers.add(task)
        conn = ServerConnection()
        from splitrender.protocol import NEED_DATA, Error, Hello

        while True:
            data = await reader.read(65536)
            conn.receive_data(data)
            if not data:
                break
            while (ev := conn.next_event()) is not NEED_DATA:
                if isinstance(ev, Hello) and self.answer is not None:
                    writer.write(conn.send(self.answer))
                    await writer.drain()
                elif isinstance(ev, Error):
                    self.errors.append(ev)
        writer.close()


async def _client_against(answer: Welcome | None, timeout_s: float) -> tuple[BaseException, list[Any], int]:
    from splitrender.client.session import ClientConfig, LiveClient

    srv = _MuteServer(answer)
    port = await srv.start()
    try:
        with pytest.raises(PeerTimeoutError) as err:
            await LiveClient(ClientConfig(port=port, connect_timeout_s=timeout_s, methods=("video",))).run()
    finally:
        await srv.close()
    return err.value, srv.errors, port


def test_no_welcome_is_a_timeout_naming_what_from_where_and_how_long() -> None:
    exc, errors, port = asyncio.run(_client_against(None, 0.3))
    assert str(exc) == f"no Welcome from 127.0.0.1:{port} within connect_timeout_s 0.3 s"
    assert isinstance(exc, TimeoutError)
    assert [(e.code, e.text) for e in errors] == [(408, f"client: {exc}")]


def test_no_session_data_is_a_timeout_naming_what_from_where_and_how_long() -> None:
    w = welcome("video", {}, session_data_bytes=1000, session_data_crc=0)
    exc, errors, port = asyncio.run(_client_against(w, 0.3))
    assert str(exc) == (f"no session data (0 of 1000 bytes received) from 127.0.0.1:{port} within connect_timeout_s "
                        "0.3 s")
    assert [(e.code, e.text) for e in errors] == [(408, f"client: {exc}")]


def test_the_cli_reports_the_timeout_and_exits_2(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
                                                 tmp_path: Any) -> None:
    import splitrender.client.cli as client_cli
    from splitrender.cli import main

    made = client_cli.config_from_args
    monkeypatch.setattr(client_cli, "config_from_args",
                        lambda ns: dataclasses.replace(made(ns), connect_timeout_s=0.2))  # type: ignore[type-var]

    import threading

    loop = asyncio.new_event_loop()
    srv = _MuteServer(None)
    port = loop.run_until_complete(srv.start())
    t = threading.Thread(target=loop.run_forever, daemon=True)
    t.start()
    try:
        assert main(["client", "--port", str(port), "--out", str(tmp_path / "out")]) == 2
    finally:
        asyncio.run_coroutine_threadsafe(srv.close(), loop).result(10)
        loop.call_soon_threadsafe(loop.stop)
        t.join(5)
        loop.close()
    assert capsys.readouterr().err == (f"splitrender: error: no Welcome from 127.0.0.1:{port} within connect_timeout_s "
                                       "0.2 s\n")
