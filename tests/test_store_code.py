"""A stored run is reused only while its method's code is the code that made it (``experiments/store.py``)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from splitrender.experiments import store as store_mod
from splitrender.experiments.store import CODE_FILE, ResultStore, method_digest, source_digest
from splitrender.sim.config import RunConfig

METHODS = Path(store_mod.__file__).resolve().parents[1] / "methods"


def _methods_copy(tmp_path: Path) -> Path:
    dst = tmp_path / "pkg" / "methods"
    shutil.copytree(METHODS, dst, ignore=shutil.ignore_patterns("__pycache__"))
    return dst


def test_a_method_s_digest_follows_its_package_the_packages_it_imports_and_the_shared_base(tmp_path: Path) -> None:
    m = _methods_copy(tmp_path)

    def digests() -> dict[str, str]:
        return {k: source_digest(m / k / "config.py", m) for k in ("sas", "tss", "warp")}

    before = digests()
    assert len(set(before.values())) == 3
    assert source_digest(m / "sas" / "config.py", m) == before["sas"], "stable"
    # a sas shader: sas and tss (whose geometry coding imports sas's) change, warp does not
    shader = next((m / "sas" / "shaders").iterdir())
    shader.write_bytes(shader.read_bytes() + b"\n")
    after = digests()
    assert after["sas"] != before["sas"] and after["tss"] != before["tss"] and after["warp"] == before["warp"]
    # the shared base changes every method's
    (m / "base.py").write_text((m / "base.py").read_text() + "\n# changed\n")
    assert all(a != b for a, b in zip(digests().values(), after.values()))
    # a method defined in one module outside the package tree: that file alone (and the shared base)
    single = tmp_path / "mymethod.py"
    single.write_text("X = 1\n")
    d0 = source_digest(single, m)
    single.write_text("X = 2\n")
    assert source_digest(single, m) != d0


def test_the_store_reruns_a_run_its_method_s_code_did_not_make(tmp_path: Path) -> None:
    cfg = RunConfig(method="video", scene="minimal", duration_s=0.1)
    st = ResultStore(tmp_path)
    assert not st.has(cfg)
    d = st.save(cfg, {"mean_psnr_db": 30.0}, [{"frame": 0}], [{"frame_id": 0}])
    code = json.loads((d / CODE_FILE).read_text())
    assert code["method"] == "video" and code["method_digest"] == method_digest("video")
    assert st.has(cfg)
    (d / CODE_FILE).write_text(json.dumps({**code, "method_digest": "0" * 16}))
    assert not st.has(cfg), "made by other code of its method: stale"
    (d / CODE_FILE).unlink()
    assert not st.has(cfg), "a store that kept no digest: stale"
    (d / CODE_FILE).write_text("not json")
    assert not st.has(cfg)
    st.save(cfg, {"mean_psnr_db": 30.0}, [{"frame": 0}], [{"frame_id": 0}])
    assert st.has(cfg)
    assert method_digest("video") != method_digest("atw")
