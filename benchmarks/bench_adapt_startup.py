"""Rate adaptation from the first second (issue 48, part 1): start low, probe up, no start-up queue.

Virtual time, the ``minimal`` scene, the ``walk`` trace, 320x180, 8 s, 20 ms each way, ``--adapt full``, for
``video``, ``atw``, ``warp`` and ``sas`` over two links from t = 0: a 1 Mbit/s bottleneck (the issue's case: the
estimate used to start at 2 Mbit/s and every stream ran at its method's own crf for its first frames, so the link's
queue filled before the first over-use was seen) and a 20 Mbit/s one (where a low start must not cost the method its
own rate for long).  Per run:

* p95 update age over the whole run, start included (the issue's target: at most 150 ms on the 1 Mbit/s link), and
  per second;
* the mean rate sent and the rate of the last 4 s;
* for each controlled stream the cap calibration gave (its method's own rate, or the link's: provisional) and when.

``--before PATH`` runs the same from a ``git worktree`` of the commit before the change, in the same invocation
(each configuration in its own process, ``PYTHONPATH`` picking the tree).  Writes
``benchmarks/results/bench_adapt_startup.json``.

    python benchmarks/bench_adapt_startup.py [--before /tmp/adapt_head] [--methods video,sas]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _trees import commit_of, run_in_tree  # noqa: E402  (beside this script)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "bench_adapt_startup.json"
METHODS = ("video", "atw", "warp", "sas")
LINKS = {"1 Mbit/s": "delay 20ms rate 1mbit", "20 Mbit/s": "delay 20ms rate 20mbit"}
DURATION_S = 8.0

CHILD = r"""
import json, math, sys
import numpy as np
from splitrender.sim.config import RunConfig
from splitrender.sim.runner import VirtualTimeRun
a = json.loads(sys.argv[1])
r = VirtualTimeRun(RunConfig(method=a["method"], scene="minimal", trace="walk", duration_s=a["duration_s"], width=320,
                             height=180, network=a["network"], transport_cc=True, adapt="full", metrics=False,
                             seed=0)).run()
ages = [(f["t_s"], f["update_age_ms"]) for f in r.frames if math.isfinite(f.get("update_age_ms", math.nan))]
p95 = lambda v: float(np.percentile(v, 95)) if v else None
per_s = [p95([x for t, x in ages if s <= t < s + 1]) for s in range(int(a["duration_s"]))]
sent = lambda lo: sum(u["bytes"] for u in r.updates if u["t_s"] >= lo) * 8 / (a["duration_s"] - lo) / 1000
caps = {}
for k in (r.updates[-1] if r.updates else {}):
    if k.startswith("adapt_") and k.endswith("_cap_kbps"):
        first = next((u["t_s"] for u in r.updates if math.isfinite(u.get(k, math.nan))), None)
        caps[k[6:-9]] = {"cap_kbps": r.updates[-1][k], "first_s": first}
print("RESULT " + json.dumps({"p95_age_ms": p95([x for _, x in ages]), "p95_age_per_s_ms": per_s,
                              "kbps": sent(0.0), "kbps_last_4s": sent(a["duration_s"] - 4.0), "caps": caps,
                              "point_moves": r.summary.get("point_moves"), "frames": len(r.frames)}))
"""


def one(tree: Path, method: str, network: str) -> dict:
    return run_in_tree(tree, CHILD, {"method": method, "network": network, "duration_s": DURATION_S},
                       f"{method} over {network}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--before", type=Path, help="a worktree of the commit before the change, run in the same invocation")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ns = ap.parse_args()
    trees = {"after": ROOT, **({"before": ns.before} if ns.before else {})}
    res: dict = {"machine": platform.platform(), "duration_s": DURATION_S, "links": LINKS,
                 "commits": {k: commit_of(t) for k, t in trees.items()}, "runs": {}}
    for method in ns.methods.split(","):
        for link, network in LINKS.items():
            for label, tree in trees.items():
                r = one(tree, method, network)
                res["runs"].setdefault(method, {}).setdefault(link, {})[label] = r
                print(f"{method:6s} {link:10s} {label:6s} p95 age {r['p95_age_ms']:6.0f} ms  per s "
                      f"{[round(x) if x is not None else None for x in r['p95_age_per_s_ms']]}  {r['kbps']:6.0f} kbit/s "
                      f"(last 4 s {r['kbps_last_4s']:6.0f})  caps {r['caps']}", flush=True)
                ns.out.parent.mkdir(parents=True, exist_ok=True)
                ns.out.write_text(json.dumps(res, indent=1))
    print(f"wrote {ns.out}")


if __name__ == "__main__":
    main()
