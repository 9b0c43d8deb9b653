"""The sweep's tables stay what they were when its engine is rebuilt from named parts (issue
24): a sweep of bench/configs/small.toml (the adaptive Dormand-Prince reference) and a
two-problem suite (DETEST A1 against its closed form, B2 against SciPy's DOP853) give the
tables stored in tests/data/sweep_regression/, recorded from the engine before the split.

Wall times are left out (they differ between two runs). Strings, integers and booleans must
be equal; floats equal to rtol 1e-9: on this machine the tables are bit-identical, but XLA on
another CPU may vectorise or fuse differently and change the last bits. A float that is zero
in exact arithmetic (an eigenvalue's imaginary part, a binding state's weight) is rounding
alone, which has no relative size: every float also passes within an absolute tolerance, a
1e-9 of its column's largest magnitude (the size its rounding is made of). An error
column is a difference of two states of size up to ~30 m, so its last bits are absolute:
err* columns pass within 1e-12. A fitted order is a slope through log errors whose
smallest lie a few thousand roundings above zero: it agrees to FIT_RTOL. A run past its stability limit multiplies every rounding by
its growth, and the growing mode may start at the size of a rounding: the errors of the
rows a table marks unstable agree to UNSTABLE_RTOL only (without XLA's machine-code
optimisation, as `make test` compiles, one moved by 8.3e-6; a changed growth, another method
or step, moves them by orders of magnitude).
To record new tables after an intended change, run this file with
STEPZOO_RECORD_REGRESSION=1 (the tests then write them and skip)."""
import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stepzoo.bench.sweep import tables as schema
from stepzoo.bench.timing.chunk_stopwatch import KEYS
from stepzoo.bench.sweep.suite import load as load_suite
from stepzoo.bench.sweep.suite import run_suite

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "sweep_regression"
RECORD = os.environ.get("STEPZOO_RECORD_REGRESSION") == "1"
RTOL, ERR_ATOL, FIT_RTOL, UNSTABLE_RTOL = 1e-9, 1e-12, 1e-6, 1e-3


def _tables(folder: Path) -> dict[str, pd.DataFrame]:
    """The folder's parquet tables without their wall-time columns."""
    out = {}
    for name in schema.PARQUET:
        df = pd.read_parquet(folder / f"{name}.parquet")
        out[name] = df.drop(columns=[c for c in df.columns if c in schema.MEASURED])
    return out


def column_atol(col: str, stored: np.ndarray) -> float:
    """The absolute tolerance of a float column (module docstring): ERR_ATOL for an error,
    else RTOL of the column's largest finite magnitude (of a column of zeros, ERR_ATOL)."""
    finite = np.abs(stored[np.isfinite(stored)])
    scale = finite.max() if finite.size else 0.0
    return ERR_ATOL if col.startswith("err") or scale == 0 else RTOL * scale


def _check(fresh: dict[str, pd.DataFrame], stored: Path):
    if RECORD:
        stored.mkdir(parents=True, exist_ok=True)
        for name, df in fresh.items():
            df.to_parquet(stored / f"{name}.parquet", index=False)
        pytest.skip(f"recorded {stored}")
    for name, df in fresh.items():
        old = pd.read_parquet(stored / f"{name}.parquet")
        assert list(df.columns) == list(old.columns), name
        assert len(df) == len(old), name
        unstable = ~old["stable"].to_numpy(bool) if "stable" in old else np.zeros(len(old), bool)
        for col in df.columns:
            a, b = df[col].to_numpy(), old[col].to_numpy()
            where = f"{stored.name}/{name}.{col}"
            if a.dtype.kind == "f" or b.dtype.kind == "f":
                a, b = a.astype(float), b.astype(float)
                grown = unstable if col.startswith("err") else np.zeros(len(a), bool)
                atol = column_atol(col, b[~grown])
                rtol = FIT_RTOL if "order" in col else RTOL
                np.testing.assert_allclose(a[~grown], b[~grown], rtol=rtol, atol=atol,
                                           equal_nan=True, err_msg=where)
                np.testing.assert_allclose(a[grown], b[grown], rtol=UNSTABLE_RTOL,
                                           atol=ERR_ATOL, equal_nan=True,
                                           err_msg=f"{where} (unstable rows)")
            else:
                assert a.dtype.kind == b.dtype.kind, where
                assert np.array_equal(a, b), where


@pytest.fixture(scope="module")
def suite(tmp_path_factory):
    folder = tmp_path_factory.mktemp("suite")
    run_suite(load_suite(DATA / "suite.toml"), folder / "out", progress=False)
    return folder / "out"


def test_the_small_sweep_gives_the_stored_tables(small_toml_sweep):
    _check(_tables(small_toml_sweep), DATA / "small")


def test_a_suite_with_exact_and_scipy_references_gives_the_stored_tables(suite):
    fresh = _tables(suite)
    fresh["orders"] = pd.read_csv(suite / "orders.csv")
    _check(fresh, DATA / "suite")


def test_each_chunk_charges_its_time_to_the_keys_of_its_work(small_toml_sweep):
    """The stopwatch's keys are the timing table's and, summed, the manifest's as before; a
    reference chunk runs no method, a method chunk integrates and runs stability tests."""
    manifest = json.loads((small_toml_sweep / "manifest.json").read_text())
    assert set(manifest["timing"]) == {"compile_s", "reference_s", "integration_s",
                                       "stability_s", "metrics_s", "total_s", "wall_s"}
    assert set(manifest["timing"]["compile_s"]) == {"reference", *manifest["methods"]}
    for chunk in sorted((small_toml_sweep / "chunks").iterdir()):
        row = pd.read_parquet(chunk / "timing.parquet").iloc[0]
        assert list(row.index) == [*KEYS, "chunk", "method", "total_s"], chunk.name
        assert all(row[k] >= 0 for k in KEYS) and sum(row[k] for k in KEYS) <= row["total_s"]
        if row["method"] == "reference":
            assert row["integration_s"] == row["stability_s"] == 0 < row["reference_s"]
        else:
            assert row["integration_s"] > 0 and row["stability_s"] > 0, chunk.name
