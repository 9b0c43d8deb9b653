"""A suite: several problems in one sweep config, swept into one results folder.

Each `[[problem]]` table is a problem: a model with its own horizon, steps, envelope and
settings. A problem's keys replace the config's top-level ones of the same name, except that
the settings tables ([steps], [reference], [stability], [chunks], [trajectories], [timing],
[limits], [newton]) are merged key by key; a problem may have methods of its own (explicit
methods on a stiff problem need a finer grid than the implicit ones: two problems of one
model).
A problem without a horizon runs over its built-in model's published interval; one without an
envelope runs its model's default problem (the envelope is then its first state's initial
value alone). Each problem is swept into its own folder, an ordinary sweep folder that tune,
report and verdict read as any other; the suite folder holds their tables together, each row
with its `problem`, and orders.csv: observed against declared order, method by problem."""
from __future__ import annotations

import hashlib
import json
import re
import shutil
import time
import types
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from pydantic import Field

from stepzoo import config_schema, environment
from stepzoo.bench.sweep import metrics
from stepzoo.bench.sweep import tables as schema
from stepzoo.bench.sweep import config as sweep_config
from stepzoo.bench.sweep import folder as sweep_folder
from stepzoo.bench.sweep.engine import _finite, _parquet, run_sweep
from stepzoo.errors import UsageError
from stepzoo.output import atomic_write, to_json
from stepzoo.results_folder import claim

SETTINGS = {"steps", "reference", "stability", "chunks", "trajectories", "timing", "limits",
            "newton"}
LABEL = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
ORDERS = "orders.csv"


# A problem's table: a sweep config's keys, each optional (the top level's fill in); its name
# labels the problem (default: its model's name).
ProblemTable = config_schema.optional(
    sweep_config.SweepConfig, "ProblemTable", "[[problem]]: one problem of the suite: a sweep "
    "config's keys, over the suite's top-level ones (the settings tables merged key by key); "
    "name labels it and its folder (default: its model's name).")
# The suite's top level: a sweep config's keys, every problem's defaults.
SuiteDefaults = config_schema.optional(
    sweep_config.SweepConfig, "SuiteDefaults", "A suite's top level: a sweep config's keys, "
    "every problem's defaults.")
SuiteFile = config_schema.optional(
    sweep_config.SweepConfig, "SuiteFile", "A suite config file: several problems swept "
    "into one results folder. Its top-level keys are a sweep config's, every problem's "
    "defaults; a problem without a horizon runs over its built-in model's published "
    "interval, one without an envelope its model's default problem.",
    # tuple[ProblemTable, ...] made at run time, as ProblemTable is
    problem=(types.GenericAlias(tuple, (ProblemTable, ...)), Field(
        min_length=1, description="the problems, [[problem]] tables, in the order they are "
        "swept")))


@dataclass(frozen=True)
class SuiteConfig:
    """A validated suite: its problems in the file's order, each (label, its sweep config,
    its config as a TOML table of its own)."""
    name: str
    problems: tuple
    source: str = ""

    @property
    def labels(self) -> list[str]:
        return [label for label, _, _ in self.problems]

    @property
    def methods(self) -> tuple:
        """Every problem's methods, each once, in the order they first come."""
        return tuple(dict.fromkeys(m for _, cfg, _ in self.problems for m in cfg.methods))

    @property
    def sha256(self) -> str:
        text = json.dumps([self.name, [(label, cfg.sha256) for label, cfg, _ in self.problems]])
        return hashlib.sha256(text.encode()).hexdigest()


def is_suite(raw: dict) -> bool:
    return "problem" in raw


def load(path) -> SuiteConfig | sweep_config.SweepConfig:
    """A sweep config file: a suite when it has [[problem]] tables, else one problem."""
    from stepzoo.validate import read_toml
    raw = read_toml(path, "sweep config", "give a TOML file such as bench/configs/small.toml")
    if not is_suite(raw):
        return sweep_config.validate(raw, str(path))
    return validate(raw, str(path))


def validate(raw: dict, source: str = "config") -> SuiteConfig:
    """The suite of `raw`; UsageError with one line per mistake, of every problem at once."""
    problems = raw["problem"]
    if not (isinstance(problems, list) and problems and all(isinstance(p, dict)
                                                            for p in problems)):
        raise UsageError(f"{source}: problem must be a list of tables: [[problem]] with a model "
                         "each")
    top = {k: v for k, v in raw.items() if k != "problem"}
    # The top level's mistakes once, not once per problem that inherits them.
    config_schema.check(SuiteDefaults, top, source)
    name = top.pop("name", Path(source).stem)
    bad, out, seen = [], [], set()
    for i, prob in enumerate(problems, 1):
        merged = _merged(top, prob, source)
        label = prob.get("name", _model_name(merged.get("model")))
        if not (isinstance(label, str) and LABEL.fullmatch(label)):
            bad.append(f"{source}: problem {i}'s name {label!r} must be letters, digits, '_', "
                       "'.' or '-' (it names the problem's folder)")
            continue
        if label in seen:
            bad.append(f"{source}: two problems are named {label!r}; give each a distinct "
                       "name = \"...\"")
            continue
        seen.add(label)
        merged["name"] = label
        try:
            config_schema.check(ProblemTable, prob, f"{source} [problem {label}]")
            _defaults(merged)
            cfg = sweep_config.validate(merged, f"{source} [problem {label}]")
        except (UsageError, KeyError) as err:
            bad.append(str(err.args[0]))
            continue
        merged["methods"] = list(cfg.methods)     # a selector as of this release, by name
        out.append((label, cfg, merged))
    if bad:
        raise UsageError("\n".join(bad))
    return SuiteConfig(name, tuple(out), source)


def _model_name(model) -> str | None:
    if isinstance(model, str):
        return model
    if isinstance(model, dict) and isinstance(model.get("rhs"), str):
        return model["rhs"].rpartition(":")[2]
    return None


def _merged(top: dict, prob: dict, source: str) -> dict:
    """The problem's own config: the top-level keys, replaced by the problem's, the settings
    tables merged key by key; a user model's folder made absolute (it was relative to the
    suite's file, and the problem's config lives in another folder)."""
    out = {k: v for k, v in top.items()}
    for key, value in prob.items():
        if key in SETTINGS and isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = {**out[key], **value}
        else:
            out[key] = value
    model = out.get("model")
    if isinstance(model, dict):
        folder = model.get("path", ".")
        if isinstance(folder, str):
            out["model"] = {**model, "path": str((Path(source).resolve().parent / folder)
                                                 .resolve())}
    return out


def _defaults(merged: dict):
    """A built-in model's published interval as the horizon, and its default problem as the
    envelope, where the problem gives neither (KeyError: an unknown model, said by name)."""
    from stepzoo import dynamics
    model = merged.get("model", "dynamic5")
    if "envelope" in merged:
        pass
    elif isinstance(model, str) and model in dynamics.MODELS:
        m = dynamics.model(model)
        merged["envelope"] = {m.states[0]: {"values": [float(m.x0[0])]}}
    elif isinstance(model, dict) and isinstance(model.get("states"), list) and model["states"]:
        first = model["states"][0]
        merged["envelope"] = {first: {"values": [float(merged.get("initial", {})
                                                       .get(first, 0.0))]}}
    if "horizon" not in merged and isinstance(model, str) and model in dynamics.MODELS:
        start, end = dynamics.model(model).t_span
        merged["horizon"] = float(end - start)


# ---- the results folder -----------------------------------------------------------------

def run_suite(suite: SuiteConfig, out, resume=False, overwrite=False, progress=True,
              runner=None) -> dict:
    """Sweep every problem of `suite` into OUT/<problem>/ (resumable, each an ordinary sweep
    folder) and write the suite's tables and manifest into `out`; returns the manifest."""
    sweep_folder.check_flags(resume, overwrite)
    for _, cfg, _ in suite.problems:
        sweep_config.check_workload(cfg)
    started = time.perf_counter()
    created = environment.now()
    with claim(out, "sweep", overwrite=overwrite):
        out = Path(out)
        sweep_folder.check_start(suite, out, resume, overwrite,
                                 discard=lambda old: _discard(out, old))
        atomic_write(out / "config.toml", _config_copy(suite))
        _write_manifest(suite, out, created, None, complete=False)
        manifests = {}
        for label, cfg, merged in suite.problems:
            folder = out / label
            own = folder / "config.toml"
            with claim(folder, "sweep", overwrite=overwrite):   # marks it the sweep's
                atomic_write(own, _toml(merged).encode())
            manifests[label] = run_sweep(cfg.changed(source=str(own)), folder, resume=resume,
                                         overwrite=overwrite, progress=progress, runner=runner)
        tables = assemble(suite, out)
        for name in schema.PARQUET:
            atomic_write(out / f"{name}.parquet", _parquet(tables[name]))
        for name in schema.CSV:
            atomic_write(out / f"{name}.csv", tables[name].to_csv(index=False))
        atomic_write(out / ORDERS, orders(tables["summary"], suite.labels).to_csv(index=False))
        timing = {"total_s": round(sum(m["timing"]["total_s"] for m in manifests.values()), 3),
                  "wall_s": round(time.perf_counter() - started, 3),
                  "problems": {k: m["timing"] for k, m in manifests.items()}}
        return _write_manifest(suite, out, created, timing, complete=True)


def _discard(out: Path, old: dict):
    """What an overwritten suite folder held: its problems' folders and its tables."""
    for label in old.get("problems", []):
        if isinstance(label, str) and LABEL.fullmatch(label):
            shutil.rmtree(out / label, ignore_errors=True)
    for name in (*schema.PARQUET, *schema.CSV, ORDERS.split(".")[0]):
        for path in out.glob(f"{name}.*"):
            path.unlink()


def assemble(suite: SuiteConfig, out: Path) -> dict:
    """Every problem's tables, one after another, with a first column `problem`."""
    tables = {}
    for name in schema.PARQUET:
        parts = []
        for label in suite.labels:
            df = pd.read_parquet(out / label / f"{name}.parquet")
            df.insert(0, "problem", label)
            parts.append(df)
        tables[name] = pd.concat(parts, ignore_index=True)
    return tables


def orders(summary: pd.DataFrame, labels: list[str]) -> pd.DataFrame:
    """Observed order (median over operating points, on the asymptotic range) per method, one
    column per problem, after the declared order; NaN where it cannot be observed (see
    summary's order_status and limits' order_note) or the problem does not run the method."""
    wide = summary.pivot(index="method", columns="problem", values="order_fit_median")
    declared = summary.groupby("method")["order_declared"].first()
    wide = wide.reindex(columns=labels)
    wide.insert(0, "order_declared", declared)
    return wide.reset_index()


def _config_copy(suite: SuiteConfig) -> bytes:
    """The suite's file as swept: the user's bytes, or (with a user model) the table with
    each model's folder made absolute, so the copy still finds the module."""
    import tomllib
    src = Path(suite.source)
    text = src.read_text()
    raw = tomllib.loads(text)
    if not any(isinstance(m.get("model"), dict) for m in [raw, *raw["problem"]]):
        return text.encode()
    for table in [raw, *raw["problem"]]:
        if isinstance(table.get("model"), dict):
            table["model"] = _merged({}, {"model": table["model"]}, suite.source)["model"]
    return (f"# {src.name} as swept, each model.path made absolute\n" + _toml(raw)).encode()


def _toml(table: dict) -> str:
    import tomli_w
    return tomli_w.dumps(table)


def _write_manifest(suite: SuiteConfig, out: Path, created, timing, complete) -> dict:
    manifest = {
        "config_sha256": suite.sha256, "config_name": suite.name, "complete": complete,
        "problems": suite.labels, "methods": list(suite.methods),
        "models": {label: cfg.spec.name for label, cfg, _ in suite.problems},
        "problem_sha256": {label: cfg.sha256 for label, cfg, _ in suite.problems},
        "timing": timing, "order_fit": metrics.ORDER_RULE,
        "order_tolerance": metrics.ORDER_TOL,
        **environment.provenance("sweep", created, environment.now() if complete else None),
    }
    atomic_write(out / "manifest.json", to_json(_finite(manifest)) + "\n")
    return manifest
