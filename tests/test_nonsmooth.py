"""What limits the step where the model is not smooth: a steering clamp crossed at a known
time along the reference is found there (within one step) and named, and the fitted order it
caps says so; a `where` switch and the CommonRoad steering stop are jumps of f; the smooth
built-in models (DETEST, the linear-tyre bicycle) are never flagged."""
import json
import tomllib
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from stepzoo import dynamics
from stepzoo.bench.model import nonsmooth
from stepzoo.bench.sweep.engine import run_sweep
from stepzoo.bench.sweep.config import load

USER = Path(__file__).resolve().parent / "user_model"
DETEST = Path(__file__).resolve().parents[1] / "bench" / "configs" / "detest.toml"


@pytest.fixture(scope="module")
def clamp_sweep(tmp_path_factory):
    """(config, its sweep folder) of the steering-clamp model, rk4 alone."""
    out = tmp_path_factory.mktemp("clamp")
    text = (USER / "steer_clamp.toml").read_text().replace('["heun", "rk4"]', '["rk4"]') \
        .replace('path = "."', f'path = "{USER}"')
    (out / "clamp.toml").write_text(text)
    cfg = load(out / "clamp.toml")
    run_sweep(cfg, out / "sweep", progress=False)
    return cfg, out / "sweep"


def test_a_steering_clamp_is_flagged_where_the_reference_crosses_it(clamp_sweep):
    cfg, folder = clamp_sweep
    limits = pd.read_parquet(folder / "limits.parquet")
    crossing = 0.42 / limits["rate"]                      # [s] delta = rate t reaches 0.42
    assert np.all(np.abs(limits["nonsmooth_t"] - crossing) <= cfg.hs[0])
    assert (limits["nonsmooth_what"] == "delta").all()
    assert (limits["nonsmooth_kind"] == "kink").all()
    assert (limits["nonsmooth_events"] == 1).all()
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["nonsmooth"] == nonsmooth.RULE                  # the rule, with the folder
    summary = pd.read_csv(folder / "summary.csv").iloc[0]
    assert summary["order_fit_median"] < 4 - 0.2           # rk4's order is capped ...
    assert summary["order_status"] == "limited by non-smooth f"   # ... and says why
    assert summary["nonsmooth_points"] == 2
    assert "delta (kink)" in summary["nonsmooth_note"]
    assert "land a step on the event" in summary["nonsmooth_note"]


def switch(t, x, u, p):
    """x0 runs at rate 1; x1 starts moving once x0 passes 0.3: f jumps at t = 0.3 s."""
    return jnp.stack([jnp.ones_like(x[0]), jnp.where(x[0] > 0.3, 1.0, 0.0)])


def test_a_where_switch_is_a_jump_of_f_at_its_time():
    ts = np.linspace(0.0, 1.0, 101)
    xs = np.stack([ts, np.maximum(ts - 0.3, 0.0)], axis=1)[None]
    event, = nonsmooth.detect(switch, ts, xs, np.zeros((1, 0)), {}, ("x0", "x1"), (),
                              1e-10, 1e-12)
    assert abs(event.t - 0.3) <= ts[1] and (event.what, event.kind) == ("x1", "jump")


def finest_steps() -> dict:
    """{DETEST problem: its finest step [s] in bench/configs/detest.toml}."""
    raw = tomllib.loads(DETEST.read_text())
    default = raw["steps"]["h"]["min"]
    return {p["model"]: p.get("steps", {}).get("h", {}).get("min", default)
            for p in raw["problem"]}


def test_the_smooth_builtin_models_are_never_flagged(tiny_sweep):
    """DETEST at the suite's finest steps along its own solutions, and the linear-tyre
    bicycle's sweep."""
    flagged = {}
    for name, h in finest_steps().items():
        m = dynamics.MODELS[name]
        ts = m.t_span[0] + h * np.arange(round((m.t_span[1] - m.t_span[0]) / h) + 1)
        event, = nonsmooth.detect(m.rhs, ts, m.solution(ts)[None], np.zeros((1, 0)),
                                  {k: np.array([v]) for k, v in m.params().items()}, m.states,
                                  (), 1e-13, 1e-15)
        if np.isfinite(event.t):
            flagged[name] = event
    assert flagged == {}
    _, folder = tiny_sweep
    assert pd.read_parquet(folder / "limits.parquet")["nonsmooth_t"].isna().all()
    summary = pd.read_csv(folder / "summary.csv")
    assert (summary["nonsmooth_points"] == 0).all()
    assert "limited by non-smooth f" not in set(summary["order_status"])


def test_the_sweep_command_and_the_report_say_where_and_the_remedy(clamp_sweep, capsys):
    from stepzoo.workflows.sweep import show
    from stepzoo.workflows.report import _facts
    from stepzoo.reports.load import load_sweep
    from stepzoo.reports.suite_report import order_rows
    _, folder = clamp_sweep
    show(json.loads((folder / "manifest.json").read_text()), folder)
    out = capsys.readouterr().out.splitlines()
    said = [line for line in out if line.startswith("f is not smooth")]
    assert len(said) == 1 and "2 of 2 points" in said[0] and nonsmooth.REMEDY in said[0]
    facts = dict(_facts(load_sweep(folder), None, None, [], None, folder))
    assert facts["non-smooth f"] == said[0]
    row, = order_rows({"clamp": load_sweep(folder)})        # a suite report's order table
    assert row["order_status"] == "limited by non-smooth f" and row["note"] == said[0]


def test_the_commonroad_steering_stop_is_a_jump_of_f_where_delta_reaches_it():
    """The built-in single-track model (st) sets the steering rate to 0 at delta_max, as
    CommonRoad does: steered at a constant rate from delta0, f jumps at (delta_max - delta0)
    / rate; held still, nothing is flagged."""
    from stepzoo.integrators.reference import reference
    m = dynamics.model("st")
    p = m.params()
    ts = np.linspace(0.0, 2.0, 1001)
    x0, u = m.from_rest(10.0, 0.7)
    events = []
    for rate in (0.3, 0.0):                                  # [rad/s]
        steer = u.at[0].set(rate)
        ref = reference(m.rhs, x0, steer, p, ts, 1e-10, 1e-12)
        events += nonsmooth.detect(m.rhs, ts, np.asarray(ref.x)[None],
                                   np.asarray(steer)[None],
                                   {k: np.array([v]) for k, v in p.items()}, m.states,
                                   m.inputs, 1e-10, 1e-12)
    stop, still = events
    assert abs(stop.t - (p["delta_max"] - 0.7) / 0.3) <= ts[1]
    assert (stop.what, stop.kind, stop.count) == ("delta", "jump", 1)
    assert np.isnan(still.t) and still.count == 0


def test_an_order_above_the_declared_one_is_not_blamed_on_non_smooth_f():
    """A kink lowers the observed order; rk4 fitted at 4.3 where f has one is not 'limited'."""
    from stepzoo.bench.sweep.metrics import order_status
    assert order_status(2.1, 4, "asymptotic", nonsmooth=True) == "limited by non-smooth f"
    assert order_status(4.3, 4, "no asymptotic range: x", nonsmooth=True) == \
        "no asymptotic range"
    assert order_status(4.5, 4, "asymptotic", nonsmooth=True) == "above declared"
