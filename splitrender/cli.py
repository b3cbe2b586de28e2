"""The ``splitrender`` command: demo, run, sweep, report, serve, client, shape.

Argument parsing lives here (one place to read the whole interface); each command's
work is in its subpackage and imported only when that command runs, so
``splitrender --help`` stays fast.  Only this module configures logging handlers.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from pathlib import Path
from typing import Any, Callable, Sequence

from . import __version__
from .errors import SplitRenderError
from .options import ClientOptions, ServerProtocolOptions, add_option_arguments

log = logging.getLogger("splitrender")


def _lazy(target: str) -> Callable[[argparse.Namespace], int]:
    mod, _, fn = target.partition(":")

    def call(ns: argparse.Namespace) -> int:
        return int(getattr(importlib.import_module(mod), fn)(ns) or 0)

    return call


def _common_run_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scene", default=None, help="built-in scene name (default, default_phong, minimal) or a .glb/.gltf/.obj/.ply/.dae file (default: default)")
    p.add_argument("--trace", default=None, help="built-in trace (walk, walk_fast, turn, strafe, static, orbit) or a trace file (.csv, or a QUASAR .txt path) (default: walk)")
    p.add_argument("--width", type=int, default=None, help="display width in pixels")
    p.add_argument("--height", type=int, default=None, help="display height in pixels")
    p.add_argument("--duration", type=float, default=None, help="seconds of the trace to run (default: whole trace)")
    p.add_argument("--seed", type=int, default=None, help="seed of the network model (default 0)")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="splitrender", description="Split-rendering streaming for XR and thin clients.")
    ap.add_argument("--version", action="version", version=f"splitrender {__version__}")
    ap.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-v info, -vv debug)")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("demo", help="run every method on the default scene under ideal/lan/cloud and write a report with charts")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    p.add_argument("--quick", action="store_true", help="short traces at 320x180: finishes in a few minutes on 2 CPU cores")
    p.add_argument("--methods", default=None, help="comma-separated methods (default: all available)")
    p.add_argument("--networks", default="ideal,lan,cloud", help="comma-separated network profiles or netem strings")
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: CPU count)")
    p.add_argument("--studies", action="store_true",
                   help="also run the studies that set methods beside their papers (the full demo does; with --quick "
                        "they are `splitrender study all` on their own)")
    p.add_argument("--no-studies", action="store_true", help="skip the studies (the full demo runs them)")
    p.add_argument("--fec", action="store_true", default=None, help="forward error correction on every RTP stream")
    p.add_argument("--adapt", choices=("off", "rate", "full"), default=None,
                   help="rate adaptation in every run (as run --adapt; turns transport-wide feedback on): rate, full, "
                        "or off (default)")
    _session_args(p)
    p.set_defaults(func=_lazy("splitrender.experiments.demo:main_demo"))

    p = sub.add_parser("study", help="the studies that set methods beside their papers, added to a demo's report")
    p.add_argument("names", help="a study's name, comma-separated names, or all (a wrong name lists them)")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="the demo folder (default out/demo): studies go to "
                   "OUT/studies/NAME and the report is written again")
    p.add_argument("--quick", action="store_true", help="the studies' quick settings")
    p.add_argument("--timeout", type=float, default=3600.0, help="stop studies still running after this many seconds")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes for the studies that run a grid of runs (claims, papers, link; default 2)")
    p.add_argument("--dask", default=None, metavar="ADDRESS",
                   help="run those grids on a Dask cluster (tcp://host:8786) or 'local' for a LocalCluster, as sweeps do")
    p.set_defaults(func=_lazy("splitrender.experiments.demo:main_study"))

    p = sub.add_parser("run", help="one virtual-time run: writes frames.csv, updates.csv, summary.csv and config.toml")
    p.add_argument("--method", default=None, help="streaming method (see `splitrender methods`; default video)")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help="method parameter (TOML value), repeatable, e.g. --param overscan=1.4")
    p.add_argument("--network", default=None, help="profile (ideal, lan, cloud, wifi, lte), a netem string such as 'delay 50ms 20ms loss 1%%', or a network .toml file (default ideal)")
    p.add_argument("--config", type=Path, default=None, help="TOML run config; command-line options override it")
    p.add_argument("--out", type=Path, default=Path("out/run"))
    p.add_argument("--server-fps", type=int, default=None)
    p.add_argument("--client-fps", type=int, default=None)
    p.add_argument("--predictor", default=None, help="none, cv, ca, cv_savgol, ca_savgol, perfect")
    p.add_argument("--flip-every", type=int, default=None, help="score FLIP every n-th displayed frame (0 = never)")
    p.add_argument("--ssim-sigma", type=float, default=None,
                   help="SSIM's Gaussian window in pixels (default 1.5, Wang et al.; the SAS paper's figures use 2)")
    p.add_argument("--no-metrics", dest="metrics", action="store_false", default=None,
                   help="score nothing against the ground truth (pose errors, rates and timings only; much faster)")
    p.add_argument("--clients", type=int, default=None, help="sessions against one server (shared scene producer; default 1)")
    p.add_argument("--client-traces", default=None, help="comma-separated trace per client, cycled (default: --trace)")
    p.add_argument("--client-offset", type=float, default=None, help="client i starts i * this many seconds into its trace")
    p.add_argument("--cost-model", choices=("fixed", "measured"), default=None,
                   help="processing time on the simulated clock: the modelled server/decode latencies (fixed, default) or "
                        "this machine's measured milliseconds (measured)")
    p.add_argument("--cost-scale", type=float, default=None, help="scale the measured milliseconds (0.1: a machine 10x faster)")
    p.add_argument("--fec", action="store_true", default=None,
                   help="forward error correction: an RFC 5109 parity packet per group of up to 16 RTP packets")
    p.add_argument("--transport-cc", action="store_true", default=None,
                   help="transport-wide congestion control feedback: the server estimates the path's rate "
                        "(updates.csv cc_* columns)")
    p.add_argument("--pacing", action="store_true", default=None,
                   help="with --transport-cc: RTP leaves through a pacer at 2.5x the estimated rate, not in bursts")
    p.add_argument("--adapt", choices=("off", "rate", "full"), default=None,  # pipeline.adapt.ADAPT_MODES (not imported: it loads the pipeline)
                   help="rate: every lossy video stream's encoder follows the estimated rate (turns --transport-cc on); "
                        "full: that, and the method's own knobs (resolution, atlas budget, depth bits, quad detail) "
                        "choose its operating point; off (default): fixed operating points")
    _session_args(p)
    _common_run_args(p)
    p.set_defaults(func=main_run)

    p = sub.add_parser("methods", help="list the available methods and their parameters")
    p.set_defaults(func=main_methods)

    p = sub.add_parser("sweep", help="expand a TOML sweep file into runs (cached by config hash) and write tidy tables")
    p.add_argument("file", type=Path)
    p.add_argument("--out", type=Path, default=Path("out/sweep"))
    p.add_argument("--workers", type=int, default=None, help="process pool size (default: CPU count; 1 = serial)")
    p.add_argument("--dask", default=None, metavar="ADDRESS", help="run on a Dask cluster (tcp://host:8786) or 'local' for a LocalCluster")
    p.add_argument("--report", action="store_true", help="write the HTML report when done")
    p.set_defaults(func=_lazy("splitrender.experiments.sweep:main_sweep"))

    p = sub.add_parser("report", help="write the HTML report (charts as PNG and SVG) for a results folder")
    p.add_argument("dir", type=Path)
    p.add_argument("--run", default=None, help="config key of the run to show per-frame timelines for")
    p.set_defaults(func=_lazy("splitrender.experiments.report:main_report"))

    p = sub.add_parser("stress", help="run the stability suite (where methods fail) and report per method")
    p.add_argument("--out", type=Path, default=Path("out/stress"))
    p.add_argument("--methods", default=None, help="comma-separated methods (default: every available one)")
    p.add_argument("--cases", default=None, help="comma-separated stress cases (default: all)")
    p.add_argument("--quick", action="store_true")
    p.add_argument("--workers", type=int, default=None)
    p.set_defaults(func=_lazy("splitrender.experiments.stress:main_stress"))

    p = sub.add_parser("serve", help="live asyncio server (TCP control + RTP video)")
    _add_optional(p, "splitrender.server.cli:add_serve_arguments")
    p.set_defaults(func=_lazy("splitrender.server.cli:main_serve"))

    p = sub.add_parser("client", help="live headless client: sends poses, decodes, displays, records")
    _add_optional(p, "splitrender.client.cli:add_client_arguments")
    p.set_defaults(func=_lazy("splitrender.client.cli:main_client"))

    p = sub.add_parser("capacity-trace", help="write a generated mahimahi capacity trace (steps, or cellular-like)")
    _add_optional(p, "splitrender.netsim.cli:add_trace_arguments")
    p.set_defaults(func=_lazy("splitrender.netsim.cli:main_trace"))

    p = sub.add_parser("shape", help="netem-style UDP/TCP shaping relay on loopback")
    _add_optional(p, "splitrender.netsim.cli:add_shape_arguments")
    p.set_defaults(func=_lazy("splitrender.netsim.cli:main_shape"))
    return ap


def _add_optional(p: argparse.ArgumentParser, target: str) -> None:
    mod, _, fn = target.partition(":")
    try:
        getattr(importlib.import_module(mod), fn)(p)
    except ModuleNotFoundError:  # pragma: no cover - subpackage not installed
        pass


def _parse_value(text: str) -> Any:
    import tomllib

    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _session_args(p: argparse.ArgumentParser) -> None:
    """The session cores' options, both sides, with virtual time's defaults (RunConfig keys; the live ``serve`` and
    ``client`` take their side's under the same flags)."""
    add_option_arguments(p, ClientOptions, ServerProtocolOptions, virtual=True)


def main_run(ns: argparse.Namespace) -> int:
    from .errors import ConfigError
    from .sim.config import RunConfig, session_options
    from .sim.runner import VirtualTimeRun

    base = RunConfig.from_toml(ns.config).to_dict() if ns.config else {}
    params = dict(base.get("method_params", {}))
    for kv in ns.param:
        k, sep, v = kv.partition("=")
        if not sep or not k:
            raise ConfigError(f"--param {kv!r}: expected KEY=VALUE")
        params[k.strip()] = _parse_value(v.strip())
    # the config file is the base; only options given on the command line override it
    over: dict[str, Any] = {"method_params": params}
    for k, v in (("method", ns.method), ("network", ns.network), ("scene", ns.scene), ("trace", ns.trace), ("seed", ns.seed),
                 ("width", ns.width), ("height", ns.height), ("duration_s", ns.duration), ("server_fps", ns.server_fps),
                 ("client_fps", ns.client_fps), ("predictor", ns.predictor), ("flip_every", ns.flip_every),
                 ("ssim_sigma", ns.ssim_sigma), ("metrics", ns.metrics),
                 ("clients", ns.clients), ("client_offset_s", ns.client_offset),
                 ("cost_model", ns.cost_model), ("cost_scale", ns.cost_scale), ("fec", ns.fec),
                 ("transport_cc", True if ns.adapt not in (None, "off") else ns.transport_cc), ("pacing", ns.pacing),
                 ("adapt", ns.adapt),
                 *session_options(ns).items(),  # from splitrender.sim.config
                 ("client_traces", ns.client_traces.split(",") if ns.client_traces else None)):
        if v is not None:
            over[k] = v
    base.update(over)
    cfg = RunConfig.from_dict(base)
    vt = VirtualTimeRun(cfg)  # validates method, scene, trace and network before the bar shows
    with _progress_bar(f"{cfg.method} / {cfg.network}") as bar:
        vt.progress = bar.update
        res = vt.run()
    res.write(ns.out)
    for s in res.client_summaries:
        who = f" client {s['client']}" if cfg.clients > 1 else ""
        print(f"{cfg.method} on {cfg.network}{who}: PSNR {s['mean_psnr_db']:.2f} dB "
              f"(model {s.get('mean_model_psnr_db', float('nan')):.2f}), SSIM {s['mean_ssim']:.4f}, "
              f"FLIP {s['mean_flip']:.4f}, {s['mean_kbps']:.0f} kbit/s, holes {s['mean_hole_pct']:.2f}%, "
              f"update age {s['mean_update_age_ms']:.0f} ms -> {ns.out}")
    return 0


def main_methods(ns: argparse.Namespace) -> int:
    import dataclasses

    from .methods import available_methods, get_method
    from .webrtc.messages import BROWSER_METHODS, HEADLESS_ONLY

    specs = {name: get_method(name) for name in available_methods()}
    for scene, title in ((False, "thin clients: the client draws only what the server sends"),
                         (True, "client renders the scene: it holds the whole scene (uploaded once at session start) and "
                                "draws it itself; a different class of client, scored and charted apart")):
        names = [n for n, spec in specs.items() if bool(spec.client_draws_scene) == scene]
        if not names:
            continue
        print(f"{title}:")
        for name in names:
            fields = ", ".join(f"{f.name}={f.default!r}" for f in dataclasses.fields(specs[name].config))
            print(f"  {name:8s} {specs[name].description}\n           {fields}")
            print("           browser page: " + (f"yes, {BROWSER_METHODS[name]}" if name in BROWSER_METHODS else
                                                     f"no, {HEADLESS_ONLY.get(name, 'not written for the page')}"))
            knobs = specs[name].config().adapt_knobs()
            if knobs:   # what --adapt full may lower, beside the encoders' rate (and the scalable colour's resolution)
                print("           --adapt full: " + ", ".join(f"{k.name} {'/'.join(f'{v:g}' for v in k.levels)}"
                                                           for k in knobs))
    return 0


class _Bar:
    def __init__(self, label: str) -> None:
        self.label = label
        self._progress: Any = None
        self._task: Any = None

    def __enter__(self) -> "_Bar":
        try:
            from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

            self._progress = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                                      TimeRemainingColumn(), transient=False)
            self._progress.__enter__()
            self._task = self._progress.add_task(self.label, total=None)
        except Exception:  # pragma: no cover - rich missing
            self._progress = None
        return self

    def update(self, done: int, total: int) -> None:
        if self._progress is not None:
            self._progress.update(self._task, completed=done, total=total)

    def __exit__(self, *exc: Any) -> None:
        if self._progress is not None:
            self._progress.__exit__(*exc)


def _progress_bar(label: str) -> _Bar:
    return _Bar(label)


def main(argv: Sequence[str] | None = None) -> int:
    ap = build_parser()
    ns = ap.parse_args(argv)
    level = logging.WARNING - 10 * min(ns.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return ns.func(ns)
    except SplitRenderError as exc:
        print(f"splitrender: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
