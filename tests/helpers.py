"""Helpers the test modules share: synthetic result folders with the sweep, tune and plan
contracts (and the checks of a report built from them), a results folder's tables read back,
the provenance every manifest records, the small configs several modules sweep, and a zoo
method whose runs take the full-Newton retry from the first."""
import base64
import dataclasses
import os
import shutil
import subprocess
import sys
import time
import gzip
import json
import re
from datetime import datetime
from importlib.metadata import version
from html.parser import HTMLParser
from pathlib import Path

import pytest

import jax
import numpy as np
import pandas as pd
from plotly.offline import get_plotlyjs

from stepzoo.bench.sweep.config import load
from stepzoo.bench.sweep import tables as schema
from stepzoo.integrators import driver, method

ROOT = Path(__file__).resolve().parents[1]


PNG = b"\x89PNG\r\n\x1a\n"


def retrying(name: str):
    """A copy of the zoo's method `name` (a program of its own) that the driver runs with the
    full-Newton retry compiled in from its first run (driver.retry_at_once): for a test whose
    solves fail the simplified iteration, one compiled program instead of the one without
    the retry and then the one with it, which give the same states."""
    m = dataclasses.replace(method(name))
    driver.retry_at_once(m)
    return m


# Synthetic methods: (order, stages, limit constant c in h_max = c / |lambda| scale).
METHODS = {"euler": (1, 1, 2.0), "rk4": (4, 4, 2.785), "ab4": (4, 1, 0.3),
           "backward_euler": (1, 1, np.inf)}


STEPS = [0.005, 0.01, 0.02, 0.05, 0.1]


POINTS = [(2.0, 0.1), (2.0, 0.785), (15.0, 0.1), (15.0, 0.785)]      # (vx m/s, delta rad)


def lam_of(vx):
    """A stand-in lateral eigenvalue [1/s] that scales like 1/vx, as the real ones do."""
    return complex(-60.0 / vx, 25.0 / vx)


def err_of(method, h):
    p = METHODS[method][0]
    return 3.0 * h ** p


def write_sweep(folder):
    """A finished sweep folder: its config implies exactly the rows written below."""
    folder.mkdir(parents=True)
    (folder / "config.toml").write_text(
        'horizon = 1.0\nmethods = ["euler", "rk4", "ab4", "backward_euler"]\n'
        f"[envelope]\nvx = [2.0, 15.0]\ndelta = [0.1, 0.785]\n[steps]\nh = {STEPS}\n"
        # The point of the synthetic trajectories below, named: the report draws them.
        "[trajectories]\nvx = 15.0\ndelta = 0.785\n")
    (folder / "manifest.json").write_text(json.dumps(
        {"config_sha256": load(folder / "config.toml").sha256, "complete": True,
         "timing": {"repeats": 3}, "blowup_rule": "|x| > 1e6",
         "trajectory_point": {"vx": 15.0, "delta": 0.785}}))
    runs, limits = [], []
    for name, (p, stages, c) in METHODS.items():
        for i, (vx, delta) in enumerate(POINTS):
            h_max = c / abs(lam_of(vx))
            for h in STEPS:
                stable = h < h_max
                e = err_of(name, h) if stable else np.nan
                runs.append(dict(method=name, h=h, point=i, vx=vx, delta=delta, stable=stable,
                                 blowup_t=np.nan if stable else 1.0, err_X=e, err_Y=e,
                                 err_psi=e, err_vy=e, err_r=e, err_pos=e, err_final=e,
                                 evals_per_s=stages / h, time_per_step_s=1e-6 * stages))
            limits.append(dict(method=name, point=i, vx=vx, delta=delta, h_pred=h_max,
                               h_meas=h_max * 1.01 if np.isfinite(h_max) else np.nan,
                               ratio=1.01, order_declared=p, order_fit=p + 0.02))
    pd.DataFrame(runs).to_parquet(folder / "runs.parquet")
    pd.DataFrame(limits).to_parquet(folder / "limits.parquet")
    pd.DataFrame(limits).to_csv(folder / "limits.csv", index=False)
    summary = [dict(method=n, family="explicit RK", order_declared=p, order_fit_median=p + 0.02,
                    real_interval=c, imag_interval=0.0,
                    h_meas_min=1.01 * c / abs(lam_of(2.0)), h_pred_min=c / abs(lam_of(2.0)),
                    worst_ratio=1.01) for n, (p, _, c) in METHODS.items()]
    pd.DataFrame(summary).to_csv(folder / "summary.csv", index=False)
    pd.DataFrame([dict(point=i, vx=vx, delta=d, lam_re=lam_of(vx).real, lam_im=s * lam_of(vx).imag)
                  for i, (vx, d) in enumerate(POINTS) for s in (1, -1)]
                 ).to_parquet(folder / "eigenvalues.parquet")
    traj = []
    t = np.linspace(0.0, 2.0, 201)
    r_ref = 0.5 * (1 - np.exp(-3 * t))
    for name, h, growth in [("reference", 0.0, 0.0), ("euler", 0.01, 0.0), ("euler", 0.2, 6.0),
                            ("rk4", 0.05, 0.0), ("rk4", 0.3, 8.0)]:
        r = r_ref * (1 + 0.02 * h) + (np.expm1(growth * t) if growth else 0.0)
        psi = np.cumsum(r) * (t[1] - t[0])
        traj += [dict(method=name, h=h, t=ti, X=15 * np.cos(pi), Y=15 * np.sin(pi), psi=pi,
                      vy=-0.1 * ri, r=ri) for ti, ri, pi in zip(t, r, psi)]
    pd.DataFrame(traj).to_parquet(folder / "trajectories.parquet")
    return folder


def write_tuned(path, h=0.02):
    path.write_text(
        f'method = "rk4"\nh = {h}\nwhy = "cheapest under the tolerance"\npos_tol_m = 0.1\n'
        'margin = 0.2\ncost_evals_per_s = 200.0\ncost_time_per_s = 0.0002\n'
        'sweep_config_sha256 = "abc123"\nprovenance = "test"\n\n'
        '[envelope]\nvx = [2.0, 15.0]\npoints = 4\n\n'
        '[[runners_up]]\nmethod = "ab4"\nh = 0.005\ncost_evals_per_s = 200.0\n'
        'cost_time_per_s = 0.0002\nreason = "stability limit"\n')
    return path


def write_plan(folder, name="street"):
    plan = folder / name
    plan.mkdir(parents=True)
    grid = np.zeros((40, 60), bool)
    grid[:10, 20:25] = True                         # an obstacle near the bottom (row 0)
    np.save(plan / "map.npy", grid)
    path = [[0.1 * i, 2.0 + 0.5 * i, 2.0 + 0.3 * i, 0.5] for i in range(40)]
    record = {"scenario": name, "status": "exact", "reason": "reached the goal",
              "path": path, "vehicle": {"length": 4.5, "width": 1.8},
              "stats": {"expansions": 12, "nodes": 40, "search_s": 0.3, "connect_s": 0.1,
                        "path_length_m": 23.0, "connect_tf_s": 2.0, "seed": 0,
                        "method": "rk4", "h": 0.02},
              "start": [2.0, 2.0, 0.0], "goal": [22.0, 14.0, 0.5],
              "tree": [[[2.0, 2.0], [4.0, 3.0], [6.0, 3.5]], [[2.0, 2.0], [4.0, 1.0]]],
              "map": {"file": "map.npy", "resolution": 0.5, "origin": [0.0, 0.0]}}
    (plan / "plan.json").write_text(json.dumps(record))
    return plan


class _Page(HTMLParser):
    """Collects ids, image sources and every attribute value that could address a resource."""
    def __init__(self):
        super().__init__()
        self.ids, self.imgs, self.refs = set(), [], []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if "id" in attrs:
            self.ids.add(attrs["id"])
        if tag == "img":
            self.imgs.append(attrs.get("src", ""))
        self.refs += [v for k, v in attrs.items() if k in ("src", "href", "srcset") and v]


def plots(text) -> dict:
    """The page's interactive figures, unpacked: {plot id: {"data", "layout", "config"}}."""
    found = re.findall(r'<script type="application/octet-stream" class="plot-spec" '
                       r'data-for="([^"]+)">([^<]*)</script>', text)
    return {key: json.loads(gzip.decompress(base64.b64decode(packed)))
            for key, packed in found}


def check_report(out, n_plans=1):
    """Assert the report in `out` is a self-contained page with Figures 1-7, each interactive
    with a static copy, plotly.js inlined once, the environment appendix, and no path of
    this machine; return its text."""
    text = (out / "index.html").read_text()
    page = _Page()
    page.feed(text)
    page.close()
    assert text.lstrip().startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    assert '<meta name="viewport" content="width=device-width' in text
    # The library's own text names websites (licences, map styles it never loads here): the
    # page around it must name none, and nothing may load from one (browser test).
    tag = '<script id="plotly-js" type="application/octet-stream">'
    head, js, rest = re.split(f'{tag}|</script>\n</head>', text, maxsplit=2)
    # Packed (gzip, base64), it is the whole library, once.
    assert gzip.decompress(base64.b64decode(js)).decode() == get_plotlyjs()
    assert text.count(tag) == 1
    assert "http://" not in head + rest and "https://" not in head + rest
    assert str(out.parent) not in text and str(Path.home()) + "/" not in text
    assert not [r for r in page.refs if r.startswith("//") or ":" in r.split("#")[0]]
    assert {f"fig{i}" for i in range(1, 8)} <= page.ids
    assert {f"plot{i}-1" for i in range(1, 7)} <= page.ids
    assert {f"plot7-{i + 1}" for i in range(n_plans)} <= page.ids
    assert set(plots(text)) == {f"plot{i}-1" for i in range(1, 7)} | {
        f"plot7-{i + 1}" for i in range(n_plans)}          # each plot with its figure
    assert "appendix" in page.ids and "float precision" in rest
    assert len(page.imgs) == 6 + n_plans
    for src in page.imgs:
        assert (out / src).is_file(), src
        assert (out / src).read_bytes()[:8] == PNG, src
    md = (out / "summary.md").read_text()
    for i in range(1, 8):
        assert f"## Figure {i}." in md
    return text


TABLES = ("runs", "limits", "eigenvalues", "trajectories", "summary")


TIMED = schema.MEASURED


def read_tables(folder):
    out = {}
    for name in TABLES:
        df = pd.read_parquet(folder / f"{name}.parquet")
        out[name] = df.drop(columns=[c for c in df.columns if c in TIMED])
    return out


def check_provenance(manifest: dict, written_by: str):
    """The environment keys every manifest carries, checked against this very process."""
    assert manifest["written_by"] == written_by
    assert isinstance(manifest["command_line"], str) and manifest["command_line"]
    started = datetime.fromisoformat(manifest["started"])
    assert started <= datetime.fromisoformat(manifest["finished"])
    env = manifest["environment"]
    machine = env["machine"]
    assert machine["cores"] >= 1 and machine["memory_gib"] > 0 and machine["cpu"]
    assert machine["system"] and machine["python_version"].count(".") == 2
    for name in ("jax", "jaxlib", "numpy", "casadi"):
        assert env["packages"][name] == version(name)
    assert env["jax"]["backend"] == jax.default_backend()
    assert len(env["jax"]["devices"]) == jax.device_count() >= 1
    assert env["jax"]["float"] == "float64"          # the tests run in float64 (conftest)
    assert env["stepzoo"]["version"] == version("stepzoo")
    commit = env["stepzoo"]["commit"]
    assert commit is None or len(commit) == 40


SOLVER_FAILURE_CONFIG = """
name = "vdp-failures"
model = "vdp1000"
horizon = 10.0
methods = ["euler", "backward_euler"]

[envelope]
y1 = { values = [1.5] }

[steps]
h = { values = [1.0, 10.0] }

[reference]
rtol = 1e-8
atol = 1e-10

[stability]
rule = "blowup"
steps = 50
h_probe_max = 10.0
rel_tol = 0.05

[chunks]
points = 1

[timing]
rounds = 1
"""


# The smallest sweep that still has several chunks: 2 methods x 2 points, a chunk per point.
TINY_SWEEP = """name = "tiny"
horizon = 0.5
methods = ["euler", "heun"]
[envelope]
vx = [6.0, 20.0]
delta = [0.3]
[steps]
h = [0.01, 0.05, 0.1]
[stability]
rule = "blowup"
steps = 200
[chunks]
points = 1
[trajectories]
vx = 20.0
delta = 0.3
"""


# Several commands in one new process, each through main(), the entry point of the `stepzoo`
# command and of `python -m stepzoo` (test_a_full_stdout_is_one_line runs that one itself):
# one start-up instead of one a command. Prints [[status, stderr], ...] as JSON, each
# command's stdout kept apart.
EACH = """import contextlib, io, json, sys
from stepzoo.cli import main
done = []
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        done.append((main(argv), err.getvalue()))
print(json.dumps(done))
"""


def each_command(*argvs) -> list:
    """The stepzoo argument lists `argvs` as a command line of one process that runs EACH."""
    return [sys.executable, "-c", EACH, json.dumps([list(map(str, a)) for a in argvs])]


def as_user(*argvs):
    """[(status, stderr)] of `stepzoo ARGV` for each ARGV, run one after the other in one new
    process with file modes enforced: as root, without the capabilities that let root ignore
    them (setpriv)."""
    cmd = each_command(*argvs)
    if os.geteuid() == 0:
        cmd = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search", "--", *cmd]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stderr == ""            # nothing past the commands' own captured lines
    return json.loads(proc.stdout)


def modes_enforced() -> str | None:
    """Why file modes cannot be enforced on a command here, or None."""
    if os.geteuid() != 0:
        return None
    if shutil.which("setpriv") is None:
        return "running as root without setpriv, which drops root's override of file modes"
    import tempfile
    with tempfile.NamedTemporaryFile() as closed:
        os.chmod(closed.name, 0)
        probe = subprocess.run(["setpriv", "--bounding-set", "-dac_override,-dac_read_search",
                                "--", "test", "-r", closed.name], capture_output=True)
    if probe.returncode == 0 or probe.stderr:
        return "setpriv cannot drop root's override of file modes in this container"
    return None


needs_modes = pytest.mark.skipif(modes_enforced() is not None,
                                 reason=str(modes_enforced()))


def private_tmpfs() -> str | None:
    """Why a small file system cannot be made here, or None."""
    if shutil.which("unshare") is None:
        return "no unshare to make a private mount namespace"
    probe = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c",
                            "mount -t tmpfs -o size=64k tmpfs /mnt"], capture_output=True)
    if probe.returncode:
        return f"cannot mount a small tmpfs here ({probe.stderr.decode().strip()})"
    return None


def two_state_config(folder: Path, casadi: str, path: Path) -> Path:
    """folder/two_states.toml: a one-step euler sweep of the CasADi model `casadi` (module
    or saved file in `path`) of states a, b and input w, at w = 0."""
    config = folder / "two_states.toml"
    config.write_text(f"""name = "two_states"
horizon = 1.0
methods = ["euler"]
[model]
casadi = "{casadi}"
path = "{path}"
states = ["a", "b"]
inputs = ["w"]
[envelope]
w = [0.0]
[steps]
h = [0.1]
""")
    return config


def block_query(folder) -> None:
    """folder/grid.npy, a 40 x 20 m map at cell 0.5 m with a 4 x 10 m block, and folder/q.json,
    one query around the block."""
    occupied = np.zeros((40, 80), bool)
    occupied[10:30, 36:44] = True
    np.save(folder / "grid.npy", occupied)
    (folder / "q.json").write_text(json.dumps([{"id": "around", "map": "grid.npy",
                                                "cell_size": 0.5, "start": [4, 10, 0],
                                                "goal": [36, 10, 0]}]))


# `python -m stepzoo` with SIGINT's default action back, as a user's terminal has it: Python
# then installs its Ctrl-C handler. A parent that ignores SIGINT (a background job of a shell
# script) passes the ignoring on, and the command rightly keeps it there (that Ctrl-C is meant
# for another job); these tests play the user at the terminal, whose Ctrl-C does reach the
# command. An exec rather than a function run between fork and exec: JAX, loaded here, warns
# of its threads.
CTRL_C_REACHES = [sys.executable, "-c", "import os, signal, sys; signal.signal(signal.SIGINT, "
                  "signal.SIG_DFL); os.execv(sys.executable, [sys.executable, *sys.argv[1:]])",
                  "-m", "stepzoo"]


def files(folder: Path) -> dict:
    """Every file under `folder` (its lock aside) and its bytes."""
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != ".stepzoo.lock"}


def until_line(proc, words: str, timeout: float = 300) -> None:
    """Read `proc`'s stderr until a line holds `words`."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stderr.readline()
        if not line:
            raise AssertionError(f"{words!r} never came; the command ended")
        if words in line:
            return
    raise AssertionError(f"{words!r} did not come in {timeout} s")


# [s] a plan's wall times: they measure the machine, not the plan.
TIMINGS = ("search_s", "connect_s", "warmup_s", "first_solution_s", "solution_s")


def without_timings(record: dict) -> dict:
    """plan.json's content (or a plan's record) less its wall times."""
    record = json.loads(json.dumps(record))
    stats = record["stats"]
    for key in TIMINGS:
        stats.pop(key)
    for step in stats["progress"]:
        step.pop("t_s")
    return record
