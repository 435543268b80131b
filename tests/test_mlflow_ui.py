"""MLflow's UI on a sweep's store, in headless Chromium: Table 1's view lists the rows (the six of the paper and ours)
with readable RMSE(d) and RMSE(f_a). Loopback only: the server listens on 127.0.0.1 on a free port."""

from __future__ import annotations

import html
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import mlflow
import pytest

from uavturb.runs.sweep import sweep
from uavturb.runs.config import DEFAULT_SPEC, load_spec

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(CHROMIUM is None, reason="needs Chromium (Debian: apt-get install -y chromium)")]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _page_text(url: str) -> str:
    """The page's text after its scripts ran (Chromium --dump-dom), tags replaced by ' | '."""
    proc = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                           "--virtual-time-budget=40000", "--window-size=1800,1200", "--dump-dom", url],
                          capture_output=True, text=True, timeout=180)
    dom = re.sub(r"<script.*?</script>|<style.*?</style>", "", proc.stdout, flags=re.S)
    return html.unescape(re.sub(r"(\s*\|\s*)+", " | ", re.sub(r"<[^>]+>", " | ", dom)))


def test_table1_view_in_the_mlflow_ui(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    over = [f"data.root={tmp_path / 'sim'}", f"data.pairs_root={tmp_path / 'pre'}", "data.image_size=16",
            "data.window=4", "data.synthetic.n_scenes=3", "data.synthetic.trajs_per_scene=1", "data.synthetic.T=16",
            "data.synthetic.pairs=32", f"trainer.default_root_dir={tmp_path / 'runs'}", "trainer.max_epochs=2",
            "model.unfreeze_at_epoch=1"]
    res = sweep(DEFAULT_SPEC, profile="quick", seeds=1, overrides=over)
    client = mlflow.MlflowClient(uri)
    runs = {r["row"]: client.get_run(r["run_id"]) for r in res["runs"]}
    exp = client.get_experiment_by_name(res["experiment"])
    assert exp.tags["mlflow.experimentKind"] == "custom_model_development"

    port = _free_port()
    server = subprocess.Popen([sys.executable, "-m", "mlflow", "server", "--backend-store-uri", uri, "--host",
                               "127.0.0.1", "--port", str(port), "--workers", "1"], cwd=tmp_path,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 180
        while True:
            try:
                if urllib.request.urlopen(f"{base}/health", timeout=5).read() == b"OK":
                    break
            except OSError:
                pass
            assert time.monotonic() < deadline and server.poll() is None, "mlflow server did not start"
            time.sleep(2)
        text = _page_text(f"{base}/{res['view']}")
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=60)

    assert "Table 1 (ablation, quick)" in text and "7 | matching runs" in text
    header = text[text.index("| Run Name |"):]
    for column in ("test/rmse_d", "test/rmse_fa", "test/rmse_fa_1e-4N", "ablation", "seed"):
        assert f"| {column} |" in header, column
    cells = [c.strip() for c in header.split("|")]
    for row in (r.name for r in load_spec(DEFAULT_SPEC).rows):
        assert f"{row} seed 0" in cells
        m = runs[row].data.metrics
        # each row's cells: duration, test/rmse_d [m], test/rmse_fa [N], test/rmse_fa_1e-4N, ablation, seed
        k = cells.index(row, cells.index(f"{row} seed 0") + 1)
        d, fa, fa_scaled = (float(x) for x in cells[k - 3:k])
        assert d == pytest.approx(m["test/rmse_d"], rel=1e-6) and 0.01 < d < 10  # metres: readable as is
        assert fa == pytest.approx(m["test/rmse_fa"], rel=1e-6)
        assert fa_scaled == pytest.approx(1e4 * fa, rel=1e-6) and fa_scaled >= 1e-3  # 1e-4 N: reads in 3 decimals
    assert Path(tmp_path / "mlflow.db").is_file()
