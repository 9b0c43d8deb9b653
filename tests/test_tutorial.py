"""The engineer's loop of docs/tutorial-engineer-loop.md, run as a user would on a copy of its
model files (docs/examples/myvehicle) in a folder outside the package: the page shows those
very files, the lines the page says the commands print are printed (results, not timings),
the steering clamp is flagged where the reference reaches it, the CasADi model measures the
JAX model's limits bit for bit, and the exports carry the tuned TOML's numbers."""
import contextlib
import io
import json
import math
import os
import runpy
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stepzoo.cli import main as stepzoo

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "docs" / "examples" / "myvehicle"
PAGE = (ROOT / "docs" / "tutorial-engineer-loop.md").read_text()
STEER_MAX = 0.42       # [rad], the clamp of vehicle.py
pytestmark = [pytest.mark.slow, pytest.mark.e2e]    # first, in make test-e2e: tests/conftest.py


def said(prefix: str) -> str:
    """The page's line that starts with `prefix` (the same line wherever it is repeated)."""
    lines = {line for line in PAGE.splitlines() if line.startswith(prefix)}
    assert len(lines) == 1, (prefix, lines)
    return lines.pop()


def run(args, status: int = 0) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert stepzoo(args) == status
    return out.getvalue()


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    """{step: its stdout} of the tutorial's commands, run in a copy of ~/myvehicle."""
    folder = tmp_path_factory.mktemp("myvehicle")
    for f in EXAMPLE.iterdir():
        shutil.copy(f, folder)
    here = os.getcwd()
    os.chdir(folder)
    try:
        out = {
            "stability": run(["stability", "vehicle.toml", "--at", "v=5", "--at",
                              "ddelta=0.77"]),
            "sweep": run(["sweep", "vehicle.toml", "--out", "sweep", "--no-progress"]),
            "casadi": run(["sweep", "vehicle_casadi.toml", "--out", "sweep_casadi",
                           "--no-progress"]),
            # Ranked by evaluations, the choice does not depend on this machine's timings.
            "tune": run(["tune", "sweep", "--pos-tol", "0.1", "--cost", "evals",
                         "--rounds", "1", "--out", "tuned.toml"]),
            "verdict": run(["verdict", "vehicle.toml", "--method", "rk4", "--h", "0.05",
                            "--method", "euler", "--h", "0.02", "--pos-tol", "0.1",
                            "--csv", "verdict_points.csv"]),
            "acados": run(["export", "tuned.toml", "--to", "acados", "--interval", "0.1"]),
            "json": run(["export", "tuned.toml", "--to", "json", "--interval", "0.1",
                         "--out", "exported"]),
            "diffrax": run(["export", "tuned.toml", "--to", "diffrax"]),
        }
    finally:
        os.chdir(here)
    return folder, out


def test_the_page_shows_the_very_files_the_loop_runs():
    """Each code block of the page is one of the example files whole, or (the CasADi
    config's [model] table) a part of one, so what a reader copies is what was run."""
    import re
    files = {f.name: f.read_text() for f in EXAMPLE.iterdir()}
    blocks = re.findall(r"```(?:python|toml)\n(.*?)```", PAGE, re.S)
    whole = [name for block in blocks for name, text in files.items() if text == block]
    assert sorted(whole) == ["vehicle.py", "vehicle.toml", "vehicle_casadi.py"]
    assert all(any(block in text for text in files.values()) for block in blocks)


def test_stability_prints_the_page_s_eigenvalues_and_limits(loop):
    _, out = loop
    lines = out["stability"].splitlines()
    assert said("eigenvalues of df/dx at the initial state") in lines
    for name in ("euler", "rk4", "dopri5", "backward_euler"):
        assert said(f"{name:<17}") in lines


def test_the_sweep_prints_the_page_s_table_and_flags_the_clamp_where_it_is_reached(loop):
    folder, out = loop
    lines = out["sweep"].splitlines()
    for name, order in (("euler", 1), ("heun", 2), ("rk4", 4), ("trapezoidal", 2)):
        assert said(f"{name:<13}{order} ") in lines
    assert said("f is not smooth") in lines
    limits = pd.read_csv(folder / "sweep" / "limits.csv")
    crossing = STEER_MAX / limits["ddelta"]               # [s] delta = ddelta t reaches the clamp
    inside = crossing < 1.0                               # the horizon
    h_min = limits["order_h_min"].min()                   # the finest grid step [s]
    assert np.all(np.abs(limits["nonsmooth_t"][inside] - crossing[inside]) <= h_min)
    assert limits["nonsmooth_t"][~inside].isna().all()
    assert (limits["nonsmooth_what"][inside] == "delta").all()
    assert (limits["nonsmooth_kind"][inside] == "kink").all()
    # The kink costs rk4 its order where it is crossed, as the page says, and nowhere else.
    rk4 = limits[limits["method"] == "rk4"].set_index(["v", "ddelta"])["order_fit"]
    assert rk4[(15.0, 0.77)] < 2.5 and rk4[(15.0, 0.3)] > 4.0 and rk4[(5.0, 0.3)] > 4.0


def test_the_casadi_model_measures_the_jax_model_s_limits_bit_for_bit(loop):
    folder, out = loop
    assert said("f is not smooth") in out["casadi"].splitlines()
    jax_, casadi = (pd.read_csv(folder / name / "limits.csv")
                    for name in ("sweep", "sweep_casadi"))
    for column in ("h_pred", "h_meas", "nonsmooth_t", "order_fit"):
        assert jax_[column].equals(casadi[column]), column


def test_verdict_prints_the_page_s_rows_per_point(loop):
    folder, out = loop
    lines = out["verdict"].splitlines()
    for prefix in ("rk4 at h = 0.05 s on v", "euler at h = 0.02 s on v", "5   0.3     0.8162",
                   "15  0.77    0.2718", "15  0.77    0.1506", "worst error   "):
        assert {line for line in PAGE.splitlines() if line.startswith(prefix)} <= set(lines)
    assert "stable, within 20% of the limit  2       v = 5, ddelta 0.3..0.77" in lines
    assert "stable, not accurate             2       v = 15, ddelta 0.3..0.77" in lines
    rows = pd.read_csv(folder / "verdict_points.csv")
    assert len(rows) == 8
    page_csv = [line for line in PAGE.splitlines() if line.startswith("rk4,0.05,")]
    assert page_csv == (folder / "verdict_points.csv").read_text().splitlines()[1:3]


def test_tune_and_the_exports_carry_the_same_numbers(loop):
    folder, out = loop
    tuned = tomllib.loads((folder / "tuned.toml").read_text())
    # The page's choice by evals: the A-stable trapezoidal rule at the sweep's largest step.
    assert (tuned["method"], tuned["h"]) == ("trapezoidal", 1 / 12)
    runner = {r["method"]: r for r in tuned["runners_up"]}
    rk4, heun = runner["rk4"], runner["heun"]
    # acados has no trapezoidal rule: the cheapest qualifying method it has, rk4, at rk4's step.
    for prefix in ("# acados:", "ocp.solver_options.", "v         5      rk4",
                   "v         15     rk4"):
        page = {line for line in PAGE.splitlines() if line.startswith(prefix)}
        assert page and page <= set(out["acados"].splitlines()), prefix
    exported = json.loads(out["json"].split("wrote ")[0])
    acados, diffrax = exported["acados"], exported["diffrax"]
    assert acados["h_tuned_s"] == rk4["h"] and acados["method"] == "rk4"
    assert acados["sim_method_num_steps"] == math.ceil(0.1 / rk4["h"])
    assert acados["step_s"] * acados["sim_method_num_steps"] == pytest.approx(0.1)
    assert acados["step_s"] <= rk4["h"]
    # acados runs rk4, so its block has rk4's schedule, as `--to acados` prints it.
    assert acados["schedule"]["v"][0]["h_safe_s"] == rk4["h"]
    assert {r["method"] for r in acados["schedule"]["v"]} == {"rk4"}
    # diffrax has no trapezoidal rule either: it runs heun, the next qualifying method.
    assert (diffrax["method"], diffrax["dt0"]) == ("heun", heun["h"]) == ("heun", 0.025)
    assert {r["method"] for r in diffrax["schedule"]["v"]} == {"heun"}
    assert (exported["method"], exported["h"]) == ("trapezoidal", 1 / 12)
    # A-stable: no limit measured anywhere, so the tuned schedule's stable step is unbounded.
    assert all(r["h_stable_s"] is None for r in exported["schedule"]["v"])
    schedule = pd.read_csv(folder / "exported" / "schedule.csv")
    page_schedule = [line for line in PAGE.splitlines()
                     if line.startswith(("v,", "ddelta,", "variable,value"))]
    # The page's numbers to rounding: err_pos_max is a difference of positions of metres, so
    # its last bits are absolute (another machine's last bits printed 0.0007511192950668335
    # for the page's 0.0007511192950669).
    pd.testing.assert_frame_equal(schedule, pd.read_csv(io.StringIO("\n".join(page_schedule))),
                                  check_exact=False, rtol=1e-9, atol=1e-12)
    # h_stable_s is (1 - margin) x the smallest measured limit of the method there: inf for
    # the tuned trapezoidal rule, 0.8 x heun's own limits in the diffrax block.
    limits = pd.read_csv(folder / "sweep" / "limits.csv")
    assert np.isinf(schedule["h_stable_s"]).all()
    for method, rows in (("trapezoidal", schedule.to_dict("records")),
                         ("heun", [dict(r, variable="v") for r in diffrax["schedule"]["v"]])):
        of = limits[limits["method"] == method]
        for row in rows:
            h_meas = of.loc[of[row["variable"]] == row["value"], "h_meas"].min()
            stable = row["h_stable_s"]
            assert (np.inf if stable is None else stable) == pytest.approx(
                (1 - tuned["margin"]) * h_meas, rel=1e-12)


def test_the_diffrax_snippet_ends_where_stepzoo_s_own_step_does(loop, capsys):
    pytest.importorskip("diffrax")
    import jax.numpy as jnp

    from stepzoo.bench.sweep.config import load
    from stepzoo.integrators import integrate
    folder, out = loop
    (folder / "run_diffrax.py").write_text(out["diffrax"])
    capsys.readouterr()
    runpy.run_path(str(folder / "run_diffrax.py"), run_name="__main__")
    printed = eval(capsys.readouterr().out)              # the dict of the final state it prints
    spec = load(folder / "sweep" / "config.toml").spec
    x0, u, p = spec.arrays([(5.0, 0.3)])
    own = integrate("heun", spec.rhs, jnp.asarray(x0[0]), u=jnp.asarray(u[0]),
                    p={k: jnp.asarray(v[0]) for k, v in p.items()}, h=0.025, n_steps=40)
    np.testing.assert_allclose([printed[s] for s in spec.states], np.asarray(own.x[-1]),
                               rtol=1e-12, atol=1e-12)
