"""Export: the tuned (method, h) in the terms of the tools that use it. acados' sim settings
for a shooting interval, a runnable diffrax snippet, and a step schedule, the largest safe
step per value of each envelope variable, computed from the sweep the choice came from.

A shooting interval S is split into num_steps = ceil(S / h) equal steps: the step S / num_steps
is h when S is a whole number of h, else the largest step below h that divides S: a shorter
step stays below the measured largest stable step, and a convergent method's error shrinks
with its step."""
from __future__ import annotations

import json
import math
from pathlib import Path

from stepzoo.errors import NoAnswer, UsageError
from stepzoo.config_schema import check
from stepzoo.tuned_file import TunedFile
from stepzoo.validate import read_toml

# stepzoo's methods that acados' sim integrators compute with the same Butcher tableau:
# (integrator_type, num_stages, collocation_type). acados' ERK has Euler (1 stage), the
# explicit midpoint rule (2), Kutta's third order (3) and the classical RK4 (4); its IRK is
# collocation, Gauss-Legendre (order 2s) or Radau IIA (order 2s - 1, s = 1 being backward
# Euler). Heun, the trapezoidal rule, multistep and Rosenbrock methods have no twin there.
ACADOS = {
    "euler": ("ERK", 1, None),
    "midpoint": ("ERK", 2, None),
    "rk3": ("ERK", 3, None),
    "rk4": ("ERK", 4, None),
    "backward_euler": ("IRK", 1, "GAUSS_RADAU_IIA"),
    "radau_iia3": ("IRK", 2, "GAUSS_RADAU_IIA"),
    "radau_iia5": ("IRK", 3, "GAUSS_RADAU_IIA"),
    "gauss_legendre4": ("IRK", 2, "GAUSS_LEGENDRE"),
}
# diffrax's own solvers with stepzoo's tableau; any other explicit RK method of the zoo is
# written out as a diffrax solver from its tableau.
DIFFRAX_NAMED = {"euler": "Euler", "heun": "Heun", "midpoint": "Midpoint", "dopri5": "Dopri5"}
TARGETS = ("acados", "diffrax", "json")


def load_tuned(path) -> dict:
    """The tuned config at `path` (written by `stepzoo tune`); UsageError if it is not one."""
    tuned = read_toml(path, "tuned config", "give a TOML file written by `stepzoo tune`")
    if not {"method", "h", "runners_up"} <= set(tuned):     # another kind of file: one line
        raise UsageError(f"{path} is not a tuned config (it lacks method, h or runners_up); "
                         "give a file written by `stepzoo tune`")
    check(TunedFile, tuned, str(path))
    from stepzoo.integrators import METHODS
    unknown = [m for m in [tuned["method"], *(r["method"] for r in tuned["runners_up"])]
               if m not in METHODS]
    if unknown:
        raise UsageError(f"{path} names method {unknown[0]!r}, which is not in the zoo (known: "
                         f"{', '.join(METHODS)}); give a file written by `stepzoo tune`")
    stepless = [r["method"] for r in tuned["runners_up"] if r.get("qualifies", True)
                and "h" not in r]
    if stepless:
        raise UsageError(f"{path}: runner-up {stepless[0]} qualifies but has no h; give a file "
                         "written by `stepzoo tune`, or set its qualifies = false")
    lacking = [k for k in ("margin",) if k not in tuned]
    if "pos_tol_m" not in tuned and "tol" not in tuned:
        lacking.append("pos_tol_m or tol")
    if lacking:
        raise UsageError(f"{path} lacks {' and '.join(lacking)}, which the step schedule needs; "
                         "give a file written by `stepzoo tune`")
    return tuned


def steps_for(interval_s: float, h: float) -> int:
    """Equal steps that split `interval_s` [s] into steps no longer than h [s]."""
    n = interval_s / h
    # A quotient a rounding above a whole number is that number: S = 8 h must give 8 steps.
    return max(1, math.ceil(n - 1e-9 * n))


def candidates(tuned: dict) -> list[dict]:
    """The choice, then the qualifying runners-up, in the order tune ranked them."""
    first = {"method": tuned["method"], "h": float(tuned["h"])}
    return [first, *[{"method": r["method"], "h": float(r["h"])} for r in tuned["runners_up"]
                     if r.get("qualifies", "h" in r)]]


def pick(tuned: dict, usable, tool: str) -> tuple[dict, str]:
    """The first candidate `usable(method)` accepts and why it is the one; NoAnswer if none."""
    for rank, c in enumerate(candidates(tuned)):
        if usable(c["method"]):
            if rank == 0:
                return c, f"the tuned choice, {c['method']} at h = {c['h']:g} s"
            return c, (f"{tuned['method']}, the tuned choice, has no equivalent in {tool}; "
                       f"{c['method']} at h = {c['h']:g} s is the cheapest qualifying method "
                       f"that {tool} has (rank {rank + 1} of the tuning)")
    names = ", ".join(c["method"] for c in candidates(tuned))
    raise NoAnswer(f"no qualifying method of the tuning ({names}) has an equivalent in "
                   f"{tool}; tune a sweep that includes one")


def acados(tuned: dict, interval_s: float, newton: dict | None = None) -> dict:
    """acados' sim settings (AcadosOcpOptions names) for a shooting interval of interval_s.

    An implicit method also gets its Newton solve: acados' IRK runs a fixed 3 iterations by
    default (newton_tol 0 turns its stopping test off), where the sweep iterated each solve to
    `newton`'s tolerance (the sweep's [newton], manifest.json). acados iterates with a fresh
    Jacobian (full Newton), so it gets the sweep's full-Newton limit (at least its simplified
    one) and stops once the stage residual's largest component is below the sweep's atol."""
    c, why = pick(tuned, lambda m: m in ACADOS, "acados")
    kind, stages, collocation = ACADOS[c["method"]]
    n = steps_for(interval_s, c["h"])
    out = {"integrator_type": kind, "sim_method_num_stages": stages,
           "sim_method_num_steps": n}
    if collocation:
        out["collocation_type"] = collocation
        from dataclasses import asdict
        from stepzoo.integrators.newton import NewtonOptions
        nt = {**asdict(NewtonOptions()), **(newton or {})}     # unrecorded: the defaults
        out["sim_method_newton_iter"] = int(max(nt["max_iter"], nt["max_iter_full"]))
        out["sim_method_newton_tol"] = float(nt["atol"])
    return {**out, "method": c["method"], "h_tuned_s": c["h"], "interval_s": interval_s,
            "step_s": interval_s / n, "why": why}


def acados_text(a: dict) -> str:
    """The settings as lines of Python for an AcadosOcp `ocp`."""
    keys = ["integrator_type", "sim_method_num_stages", "sim_method_num_steps",
            "collocation_type", "sim_method_newton_iter", "sim_method_newton_tol"]
    lines = [f"# acados: {a['why']}; a shooting interval of {a['interval_s']:g} s in steps of "
             f"{a['step_s']:.6g} s (<= h)"]
    lines += [f"ocp.solver_options.{k} = {json.dumps(a[k])}" for k in keys if k in a]
    return "\n".join(lines) + "\n"


def _diffrax_usable(name: str) -> bool:
    from stepzoo.integrators import METHODS
    return METHODS[name].family == "explicit RK"


def diffrax_settings(tuned: dict, interval_s: float | None = None) -> dict:
    """Solver, step controller and dt0 [s] for diffrax; t1 [s] is interval_s (default: the
    sweep's horizon), split into equal steps no longer than h."""
    c, why = pick(tuned, _diffrax_usable, "diffrax")
    t1 = float(interval_s if interval_s is not None else tuned.get("horizon_s", math.nan))
    if not math.isfinite(t1):
        raise UsageError("the tuned config records no sweep horizon (horizon_s absent or NaN, "
                         "as tune writes for a sweep without one); give --interval S")
    n = steps_for(t1, c["h"])
    solver = DIFFRAX_NAMED.get(c["method"], _class_name(c["method"]))
    return {"solver": f"diffrax.{solver}" if c["method"] in DIFFRAX_NAMED else solver,
            "stepsize_controller": "diffrax.ConstantStepSize", "dt0": t1 / n, "t1": t1,
            "n_steps": n, "method": c["method"], "h_tuned_s": c["h"], "why": why}


def _class_name(method: str) -> str:
    return method.upper().replace("_", "")


def _tableau_class(method: str) -> str:
    """Python source of a diffrax solver class with stepzoo's tableau of `method`."""
    from stepzoo.integrators import METHODS
    from stepzoo.integrators.stability import tableau
    m = METHODS[method]
    t = tableau(m)
    rows = ", ".join(f"np.array({list(map(float, t.a[i, :i]))!r})" for i in range(1, t.stages))
    return f'''

class {_class_name(method)}(diffrax.AbstractERK):
    """stepzoo's {method} ({m.reference}), order {m.order}, as a diffrax solver."""
    tableau = diffrax.ButcherTableau(
        c=np.array({list(map(float, t.c[1:]))!r}),
        b_sol=np.array({list(map(float, t.b))!r}),
        b_error=np.zeros({t.stages}),
        a_lower=({rows},),
    )
    interpolation_cls = diffrax.ThirdOrderHermitePolynomialInterpolation.from_k

    def order(self, terms):
        return {m.order}
'''


def diffrax_snippet(tuned: dict, sweep: Path, interval_s: float | None = None) -> str:
    """A runnable Python script: the sweep's model at its trajectory point, integrated over
    t1 with the exported solver and constant step; it prints the final state."""
    d = diffrax_settings(tuned, interval_s)
    manifest = json.loads((sweep / "manifest.json").read_text())
    point = manifest["trajectory_point"]
    custom = "" if d["method"] in DIFFRAX_NAMED else _tableau_class(d["method"])
    names = ", ".join(point)
    values = tuple(float(v) for v in point.values())
    # The sweep's path only as a string literal (repr): a folder name may hold a backslash
    # or quotes, which in the docstring would end it or start an escape.
    return f'''"""diffrax with a constant step: {d['why']}.
Integrates the model of the sweep SWEEP (its config.toml) at its operating point ({names}) =
{values} over {d['t1']:g} s in {d['n_steps']} steps of dt0 [s], and prints the final state."""
import os

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from stepzoo.bench.sweep.config import load

jax.config.update("jax_enable_x64", True){custom}

solver = {d['solver']}()
stepsize_controller = diffrax.ConstantStepSize()
dt0 = {d['dt0']!r}  # [s]
t1 = {d['t1']!r}  # [s], {d['n_steps']} steps of dt0

SWEEP = {str(sweep)!r}
spec = load(os.path.join(SWEEP, "config.toml")).spec
x0, u, p = spec.arrays([{values!r}])
args = (jnp.asarray(u[0]), {{k: jnp.asarray(v[0]) for k, v in p.items()}})
term = diffrax.ODETerm(lambda t, x, args: spec.rhs(t, x, *args))
sol = diffrax.diffeqsolve(term, solver, t0=0.0, t1=t1, dt0=dt0, y0=jnp.asarray(x0[0]),
                          args=args, stepsize_controller=stepsize_controller,
                          max_steps={d['n_steps'] + 1})
x_end = np.asarray(sol.ys[-1])
print(dict(zip(spec.states, x_end.tolist())))
'''


def sweep_of(tuned: dict, given=None) -> Path:
    """The finished sweep folder the tuned config came from (`given`, else the one it
    records); UsageError if there is none or it is another sweep."""
    from stepzoo.bench.tune.cheapest import load_results
    folder = given if given is not None else tuned.get("sweep")
    if folder is None:
        raise UsageError("the tuned config does not record its sweep folder (tuned before "
                         "stepzoo recorded it); give it with --sweep DIR")
    folder = Path(folder)
    runs, _, manifest = load_results(folder)
    if "sweep_config_sha256" not in tuned:
        raise UsageError("the tuned config lacks sweep_config_sha256, so the sweep it came from "
                         "cannot be told; give a file written by `stepzoo tune`")
    if manifest.get("config_sha256") != tuned["sweep_config_sha256"]:
        raise UsageError(f"{folder} holds another sweep than the one the tuned config was made "
                         "from (its config sha256 differs); give that sweep with --sweep DIR")
    lacking = [k for k in ("model_spec", "trajectory_point") if not isinstance(manifest.get(k),
                                                                              dict)]
    if lacking:
        raise UsageError(f"{folder / 'manifest.json'} lacks {', '.join(lacking)}: the sweep was "
                         "written by an older `stepzoo sweep`; sweep its config again into a "
                         "new folder and tune that")
    _check_swept(tuned, folder, runs)
    return folder


def sweep_newton(folder: Path) -> dict | None:
    """The [newton] options the sweep in `folder` solved with (its manifest), None if unrecorded."""
    manifest = json.loads((Path(folder) / "manifest.json").read_text())
    newton = manifest.get("newton")
    return newton if isinstance(newton, dict) else None


def _check_swept(tuned: dict, folder: Path, runs) -> None:
    """UsageError unless the choice and each qualifying runner-up is a (method, h) the sweep
    ran: one it never ran (a tuned file changed by hand) has no measurement behind it, and an
    export of it would stand on none."""
    import numpy as np
    for c in candidates(tuned):
        hs = runs.loc[runs["method"] == c["method"], "h"].to_numpy(float)
        if not np.isclose(hs, c["h"], rtol=1e-12, atol=0.0).any():
            swept = ", ".join(dict.fromkeys(runs["method"]))
            raise UsageError(f"the tuned config names {c['method']} at h = {c['h']:g} s, which "
                             f"the sweep {folder} did not run (it ran {swept}): the file was "
                             "changed after `stepzoo tune`; tune the sweep again")


def schedule(tuned: dict, sweep: Path, method: str | None = None):
    """For `method` (default: the tuned one), per value of each envelope variable (every
    other variable over its whole range): `h_safe_s`, the largest swept step [s] stable with
    the tuned margin and within its tolerance at every such point, NaN if none;
    `h_stable_s`, (1 - margin) x the smallest measured largest stable step [s] there (inf:
    never unstable); the worst error at h_safe and the point count."""
    import pandas as pd

    from stepzoo.bench.tune.cheapest import candidates as qualify
    from stepzoo.bench.tune.cheapest import check_error_column, load_results
    runs, limits, manifest = load_results(sweep)
    method, margin = method or tuned["method"], float(tuned["margin"])
    col, tol = (("err_pos", tuned["pos_tol_m"]) if "pos_tol_m" in tuned
                else ("err", tuned["tol"]))
    check_error_column(sweep, runs, manifest, col)
    runs, limits = runs[runs["method"] == method], limits[limits["method"] == method]
    variables = (manifest.get("model_spec") or {}).get("variables", [])
    rows = []
    for var in variables:
        for value in sorted(limits[var].unique()):
            r, lim = runs[runs[var] == value], limits[limits[var] == value]
            table = qualify(r, lim, tol, margin, col)
            ok = table[table["ok"]]
            best = ok.loc[ok["h"].idxmax()] if len(ok) else None
            rows.append({"variable": var, "value": float(value), "method": method,
                         "h_safe_s": float(best["h"]) if best is not None else float("nan"),
                         "h_stable_s": float((1 - margin) * lim["h_meas"].min()),
                         col + "_max": float(best[col]) if best is not None else float("nan"),
                         "points": int(lim["point"].nunique())})
    return pd.DataFrame(rows)


def schedule_records(table) -> dict:
    """The schedule as JSON: per variable, rows of value and steps (non-finite as null)."""
    def plain(v):
        return v if not isinstance(v, float) or math.isfinite(v) else None
    out = {}
    for var, rows in table.groupby("variable", sort=False):
        out[var] = [{k: plain(v) for k, v in row.items() if k != "variable"}
                    for row in rows.to_dict("records")]
    return out


def as_json(tuned: dict, path, sweep: Path, table,
            interval_s: float | None) -> dict:
    """Everything exported, for machines: the choice, the tools' settings, the schedule."""
    out = {"tuned": str(path), "sweep": str(sweep), "method": tuned["method"],
           "h": float(tuned["h"]), "cost": tuned.get("cost", "evals"),
           "interval_s": interval_s}
    try:
        out["acados"] = (acados(tuned, interval_s, sweep_newton(sweep))
                         if interval_s is not None else None)
    except NoAnswer as err:
        out["acados"] = {"error": str(err)}
    try:
        out["diffrax"] = diffrax_settings(tuned, interval_s)
    except (NoAnswer, UsageError) as err:       # no such method, or no horizon to span
        out["diffrax"] = {"error": str(err)}
    # A tool that runs another method than the tuned one (acados has no Heun) gets that
    # method's schedule with its settings, as `--to acados` and `--to diffrax` print it.
    for tool in ("acados", "diffrax"):
        other = (out[tool] or {}).get("method", tuned["method"])
        if other != tuned["method"]:
            out[tool]["schedule"] = schedule_records(schedule(tuned, sweep, other))
    out["schedule"] = schedule_records(table)
    return out
