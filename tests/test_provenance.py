"""Reproducible results: every manifest.json records the environment (machine, OS, Python,
library versions, JAX backend, devices and precision, stepzoo's version, the command line,
start and end), and each method's calibrated run is timed in repeated rounds summarised as
minimum, median, largest and interquartile range, which price every run of the method."""
import json
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stepzoo.cli import main as stepzoo
from stepzoo.bench.sweep.engine import run_sweep
from stepzoo.bench.sweep.config import load
from stepzoo.bench.timing.rounds import per_step
from helpers import check_provenance

CONFIGS = Path(__file__).resolve().parents[1] / "bench" / "configs"


def test_timing_summary_of_known_rounds():
    row = per_step([0.3, 0.1, 0.2, 0.5, 0.4], steps=10)
    assert row["time_per_step_s"] == pytest.approx(0.01)          # the minimum
    assert row["time_per_step_median_s"] == pytest.approx(0.03)
    assert row["time_per_step_max_s"] == pytest.approx(0.05)
    assert row["time_per_step_iqr_s"] == pytest.approx(0.02)      # 0.4 - 0.2, per 10 steps
    assert row["timing_rounds"] == 5


@pytest.fixture(scope="module")
def small_sweep(tmp_path_factory):
    cfg = load(CONFIGS / "small.toml").changed(methods=("euler",), timing={"rounds": 3})
    out = tmp_path_factory.mktemp("sweep")
    run_sweep(cfg, out, progress=False)
    return cfg, out


def test_sweep_prices_every_run_from_the_configured_rounds(small_sweep):
    cfg, out = small_sweep
    runs = pd.read_parquet(out / "runs.parquet")
    assert (runs["timing_rounds"] == 3).all()
    lo, mid, hi = (runs[c].to_numpy() for c in ("time_per_step_s", "time_per_step_median_s",
                                                 "time_per_step_max_s"))
    assert np.all(lo > 0) and np.all(lo <= mid) and np.all(mid <= hi)
    assert np.all((runs["time_per_step_iqr_s"] >= 0) & (runs["time_per_step_iqr_s"] <= hi - lo))


def test_sweep_manifest_records_the_environment_and_keeps_its_keys(small_sweep):
    cfg, out = small_sweep
    manifest = json.loads((out / "manifest.json").read_text())
    check_provenance(manifest, "sweep")
    assert manifest["complete"] and manifest["config_sha256"] == cfg.sha256
    assert manifest["timing_rounds"] == 3
    assert datetime.fromisoformat(manifest["created"]) <= \
        datetime.fromisoformat(manifest["started"])
    for key in ("config_name", "updated", "methods", "chunks", "n_chunks", "timing",
                "blowup_rule", "stability", "order_fit", "trajectory_point", "horizon_s",
                "vehicle", "model", "stepzoo_version"):
        assert key in manifest, key


@pytest.mark.parametrize("rounds", ["0", "2.5", "true", "5000"])
def test_timing_rounds_out_of_range_is_one_line(tmp_path, capsys, rounds):
    path = tmp_path / "bad.toml"
    path.write_text((CONFIGS / "small.toml").read_text() + f"\n[timing]\nrounds = {rounds}\n")
    assert stepzoo(["sweep", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "timing.rounds" in err
    assert not (tmp_path / "out").exists()


def test_the_page_shows_paths_near_the_report_relative_and_others_by_name(tmp_path):
    from stepzoo.reports.provenance import public_command, public_path
    report = tmp_path / "run" / "report"
    assert public_path(tmp_path / "run" / "sweep", report) == "../sweep"
    assert public_path(report, report) == "."
    assert public_path("/home/alice/data/sweep", report) == ".../sweep"
    line = f"stepzoo report /home/alice/data --out={report} --plans ../plans -q"
    assert public_command(line, report) == "stepzoo report .../data --out=. --plans ../plans -q"
