"""The sweep engine: every (method, h, operating point) of a config, in chunks of one method
by one block of points. `compute_chunk(config, chunk_id)` is pure (a Dask worker can call
it); `run_sweep` writes each chunk as it finishes, resumes, and concatenates the tables."""
from __future__ import annotations

import math
import os
import shutil
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd

from stepzoo import environment
from stepzoo.bench.sweep import chunk_tables
from stepzoo.bench.sweep import distributed
from stepzoo.bench.model import frozen_jacobian as frozen
from stepzoo.bench.sweep import limit_search
from stepzoo.bench.sweep import metrics
from stepzoo.bench.model import nonsmooth
from stepzoo.bench.sweep import reference as reference_backend
from stepzoo.bench.sweep import tables as schema
from stepzoo.bench.sweep.runs import stability_runs
from stepzoo.bench.sweep import folder as sweep_folder
from stepzoo.bench.sweep.block import Block
from stepzoo.bench.sweep.estimate import estimate
from stepzoo.bench.timing.chunk_stopwatch import Stopwatch
from stepzoo.bench.timing.rounds import RULE as TIMING_RULE
from stepzoo.errors import UsageError
from stepzoo.output import atomic_write, to_json, write_file
from stepzoo.results_folder import claim
from stepzoo.bench.sweep.config import ESTIMATES, SweepConfig, check_workload

# ---- chunks -----------------------------------------------------------------------------

def n_blocks(cfg: SweepConfig) -> int:
    return -(-len(cfg.points) // cfg.chunks.points)


def chunk_ids(cfg: SweepConfig) -> list[str]:
    """'reference-bNNN' (eigenvalues, the figure's reference) then 'METHOD-bNNN' per block."""
    blocks = range(n_blocks(cfg))
    return [f"{m}-b{i:03d}" for m in ("reference", *cfg.methods) for i in blocks]


def compute_chunk(cfg: SweepConfig, chunk_id: str, cache_: dict | None = None) -> dict:
    """The tables of one chunk, from the config alone. `cache_` (optional, any dict) keeps the
    reference solutions of a block for the next method's chunk in the same process."""
    kind, _, block = chunk_id.rpartition("-b")
    if kind not in ("reference", *cfg.methods) or not block.isdigit() \
            or int(block) >= n_blocks(cfg):
        raise ValueError(f"no chunk {chunk_id!r} in this config")
    started, watch = time.perf_counter(), Stopwatch()
    part = Block(cfg, int(block), {} if cache_ is None else cache_, watch)
    tables = chunk_tables.reference_chunk(part) if kind == "reference" else \
        chunk_tables.method_chunk(part, kind)
    tables["timing"] = pd.DataFrame([{**watch.seconds, "chunk": chunk_id, "method": kind,
                                      "total_s": time.perf_counter() - started}])
    return tables


# ---- the results folder -----------------------------------------------------------------

def run_sweep(cfg: SweepConfig, out, resume=False, overwrite=False, progress=True,
              on_chunk=None, runner=None, workers: int | None = None) -> dict:
    """Compute every missing chunk of `cfg` into `out` and write the tables; returns the
    manifest. `on_chunk(chunk_id)` is called after each chunk is safely on disk. `runner(cfg,
    chunk_ids)`, if given, computes the chunks elsewhere (`bench.sweep.distributed`) and yields
    (chunk id, tables) as they finish; by default they are computed here, on `workers`
    threads (default: one per core; `jobs`). The folder is locked meanwhile: a second sweep
    into it is refused (`results_folder`)."""
    sweep_folder.check_flags(resume, overwrite)
    check_workload(cfg)
    with claim(out, "sweep", overwrite=overwrite):
        return _fill(cfg, Path(out), resume, overwrite, progress, on_chunk, runner, workers)


def jobs(cfg: SweepConfig, todo: list[str], cache: dict, est=None) -> list:
    """The chunks `todo` as jobs for `distributed.threaded`, each yielding (chunk id, tables):
    the reference chunks first, then each method's chunks in one job (a thread compiles a
    method once), the longest first by the estimate `est` where there is one. The jobs share
    `cache`: a block's references are computed once, by the first chunk that needs them."""
    kinds = distributed.by_kind(todo)
    cost = lambda kind: 0.0 if est is None or kind not in est.methods else \
        -est.methods[kind]["chunk_s"]
    order = sorted(kinds, key=lambda kind: (kind != "reference", cost(kind)))
    return [lambda ids=kinds[kind]: ((cid, compute_chunk(cfg, cid, cache)) for cid in ids)
            for kind in order]


def _fill(cfg, out: Path, resume, overwrite, progress, on_chunk, runner, workers) -> dict:
    from tqdm import tqdm
    started = time.perf_counter()
    chunks = out / "chunks"
    old = sweep_folder.check_start(cfg, out, resume, overwrite)
    atomic_write(out / "config.toml", _config_copy(cfg))
    created = (old or {}).get("created") or datetime.now(timezone.utc).isoformat(
        timespec="seconds")
    created = (created, environment.now())      # the first call's start, and this call's
    ids = chunk_ids(cfg)
    # The manifest (the config's sha256) before the chunks folder: a folder with chunks/ is
    # one a resumed sweep can check, even where Ctrl-C stopped the first call right here.
    if old is None:
        _write_manifest(cfg, out, created, [], None, complete=False)
    chunks.mkdir(parents=True, exist_ok=True)
    for stale in chunks.glob(".*.tmp*"):           # a chunk cut off while being written
        shutil.rmtree(stale, ignore_errors=True)
    for cid, why in sweep_folder.set_aside_damaged(ids, chunks).items():
        sys.stderr.write(f"sweep: chunk {cid} is damaged ({why}); set aside as "
                         f"{chunks / f'.{cid}.damaged'}, computing it again\n")
    done = [c for c in ids if (chunks / c).is_dir()]
    _write_manifest(cfg, out, created, done, None, complete=False)
    ref_cache: dict = {}
    todo = [c for c in ids if c not in done]
    # Before a fresh sweep here: its wall time, calibrated on the first block into the cache
    # the chunks read (a cluster's workers, or a resumed sweep, are not estimated).
    workers = workers or distributed.cores()
    est = estimate(cfg, ref_cache, n_blocks(cfg), workers) if (progress and runner is None
                                                               and not done) else None
    if est is not None:
        print(f"stepzoo sweep: {est.says()}", file=sys.stderr, flush=True)
    computed = runner(cfg, todo) if runner is not None else \
        distributed.threaded(jobs(cfg, todo, ref_cache, est), workers)
    try:
        for cid, tables in tqdm(computed, total=len(todo), desc=f"sweep {cfg.name}",
                                unit="chunk", file=sys.stderr, disable=not progress):
            _write_chunk(chunks, cid, tables)
            done.append(cid)
            _write_manifest(cfg, out, created, [c for c in ids if c in done], None,
                            complete=False)
            if on_chunk is not None:
                on_chunk(cid)
    finally:            # stopped early (Ctrl-C, an error): the threads stop with it, now
        getattr(computed, "close", lambda: None)()
    t0 = time.perf_counter()
    lost = sweep_folder.missing_chunks(ids, chunks)
    if lost:
        raise UsageError(f"{chunks} lost {len(lost)} chunk(s) while this sweep ran ({lost[0]}"
                         f"{', ...' if len(lost) > 1 else ''}); tables not written: rerun with "
                         "--resume")
    tables = assemble(cfg, chunks)
    problem = sweep_folder.table_problem(cfg, tables["runs"], tables["limits"])
    if problem:
        raise UsageError(f"{out}: the chunks do not add up: {problem}; tables not written")
    for name in schema.PARQUET:
        atomic_write(out / f"{name}.parquet", _parquet(tables[name]))
    for name in schema.CSV:
        atomic_write(out / f"{name}.csv", tables[name].to_csv(index=False))
    timing = _timing(tables["timing"], time.perf_counter() - t0, time.perf_counter() - started)
    if est is not None:
        timing["estimate"] = est.record()
    return _write_manifest(cfg, out, created, ids, timing, complete=True)


def _write_chunk(chunks: Path, cid: str, tables: dict):
    """All tables of a chunk into a hidden folder, then one rename: a chunk is there whole
    or not at all."""
    tmp = chunks / f".{cid}.tmp{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name, df in tables.items():
        write_file(tmp / f"{name}.parquet", _parquet(df))
    os.replace(tmp, chunks / cid)


def _parquet(df: pd.DataFrame) -> bytes:
    import io
    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    return buf.getvalue()


def assemble(cfg: SweepConfig, chunks: Path) -> dict:
    """The final tables: the chunks' tables concatenated and sorted, plus the summary."""
    parts: dict[str, list[pd.DataFrame]] = {name: [] for name in schema.CHUNK_TABLES}
    # A table no chunk has a row of keeps its columns (DETEST A5's Jacobian is 0 at t = 0:
    # no chunk lists an eigenvalue), so that readers find the columns they check.
    empty: dict[str, pd.DataFrame] = {}
    for cid in chunk_ids(cfg):
        for name in schema.CHUNK_TABLES:
            path = chunks / cid / f"{name}.parquet"
            if path.is_file():
                df = pd.read_parquet(path)
                if len(df):
                    parts[name].append(df)
                elif len(df.columns):
                    empty.setdefault(name, df)
    tables = {}
    for name in schema.CHUNK_TABLES:
        df = pd.concat(parts[name], ignore_index=True) if parts[name] else \
            empty.get(name, pd.DataFrame())
        tables[name] = df.sort_values(schema.SORT[name], kind="stable", ignore_index=True) \
            if len(df) else df
    tables["summary"] = summary(tables["runs"], tables["limits"])
    return tables


def summary(runs: pd.DataFrame, limits: pd.DataFrame) -> pd.DataFrame:
    """One row per method: orders, stability intervals, limits and their worst agreement."""
    from stepzoo.integrators import METHODS
    from stepzoo.integrators.stability import stability_intervals
    rows = []
    for name, lim in limits.groupby("method", sort=True):
        m = METHODS[name]
        real, imag = stability_intervals(m)
        r = runs[runs["method"] == name]
        median = float(lim["order_fit"].median())
        # Folders swept before rho_max was recorded have no order_h_rho.
        h_rho = float(lim["order_h_rho"].median()) if "order_h_rho" in lim else np.nan
        flagged = int(np.isfinite(lim["nonsmooth_t"].to_numpy(float)).sum()) \
            if "nonsmooth_t" in lim else 0
        rows.append(dict(
            method=name, family=m.family, order_declared=m.order,
            order_fit_median=median,
            order_fit_min=float(lim["order_fit"].min()),
            order_fit_max=float(lim["order_fit"].max()),
            order_h_min=float(lim["order_h_min"].min()),
            order_h_max=float(lim["order_h_max"].max()),
            order_status=metrics.order_status(median, m.order, most_common(lim["order_note"]),
                                              h_rho, nonsmooth=flagged >= 0.5 * len(lim)),
            order_h_rho=h_rho,
            real_interval=real, imag_interval=imag,
            h_pred_min=float(lim["h_pred"].min()), **metrics.own_limits(lim),
            implicit=m.implicit,
            evals_per_step=float((r["evals_per_s"] * r["h"]).median()),
            points=int(lim["point"].nunique()),
            solver_failures=int((~r["converged"]).sum()) if "converged" in r else 0,
            nonsmooth_points=flagged, nonsmooth_note=nonsmooth.note(lim),
            **metrics.disagreement(lim)))
    return pd.DataFrame(rows, columns=schema.SUMMARY)


def most_common(notes: pd.Series) -> str:
    """The note most operating points share (the first in order on a tie)."""
    return str(notes.value_counts(sort=True).index[0])


def _timing(per_chunk: pd.DataFrame, assemble_s: float, wall_s: float) -> dict:
    # JAX's compiling [s] per method; "reference": the references' and the Jacobians'.
    compile_s = per_chunk.groupby("method")["compile_s"].sum()
    compile_by: dict[str, float] = {k: round(float(v), 3) for k, v in compile_s.items()
                                    if k != "reference"}
    compile_by["reference"] = round(float(per_chunk["ref_compile_s"].sum()
                                          + compile_s.get("reference", 0.0)), 3)
    seconds = {key: round(float(per_chunk[key].sum()), 3)
               for key in ("reference_s", "integration_s", "stability_s", "metrics_s")}
    seconds["metrics_s"] = round(seconds["metrics_s"] + assemble_s, 3)
    seconds["total_s"] = round(float(per_chunk["total_s"].sum()) + assemble_s, 3)
    seconds["wall_s"] = round(wall_s, 3)
    return {"compile_s": compile_by, **seconds}


def _write_manifest(cfg, out: Path, created, done, timing, complete) -> dict:
    """manifest.json; `created` is (the first call's start, this call's start) [UTC]."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        ver = version("stepzoo")
    except PackageNotFoundError:
        ver = "unknown"
    manifest = {
        "config_sha256": cfg.sha256, "config_name": cfg.name, "created": created[0],
        "updated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "complete": complete, "methods": list(cfg.methods), "chunks": list(done),
        "n_chunks": len(chunk_ids(cfg)), "timing": timing,
        "blowup_rule": metrics.BLOWUP_RULE if cfg.stability.rule == "blowup" else
        stability_runs.MODES_RULE,
        "stability": {"rule": cfg.stability.rule, "horizon_s": cfg.stability_horizon,
                      "agreement_tol": metrics.AGREE_TOL,
                      "steps": cfg.stability.steps, "growth": cfg.stability.growth,
                      "perturbation": cfg.stability.perturbation,
                      "h_probe_max_s": cfg.stability.h_probe_max,
                      "bisection_rel_tol": cfg.stability.rel_tol,
                      "narrowing": limit_search.NARROWING},
        "order_fit": metrics.ORDER_RULE,
        "nonsmooth": nonsmooth.RULE,
        "prediction": frozen.RULE,
        "trajectory_point": dict(zip(cfg.spec.variables, cfg.trajectories.point)),
        "horizon_s": cfg.horizon, "vehicle": cfg.vehicle, "model": cfg.spec.name,
        "reference": reference_backend.choose(cfg).description,
        "error_estimate": ESTIMATES[cfg.error.estimate],
        "newton": cfg.newton_options,
        "model_spec": schema.model_record(cfg.spec),
        "stepzoo_version": ver, "timing_rounds": cfg.timing.rounds,
        "timing_rule": TIMING_RULE,
        **environment.provenance("sweep", created[1], environment.now() if complete else None),
    }
    atomic_write(out / "manifest.json", to_json(_finite(manifest)) + "\n")
    return manifest


def _finite(obj):
    """JSON has no inf/NaN: write them as null."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _config_copy(cfg) -> bytes:
    """The config file as the folder keeps it: the user's own bytes, but with a user model's
    folder made absolute, so the copy still finds the module (tune and report reload it),
    and with the sweep's name first where the file gave none (the name defaults to the
    file's stem, and the copy's stem is "config": tune and report would see another sweep)."""
    import tomllib

    import tomli_w
    src = Path(cfg.source) if cfg.source else None
    if not (src and src.is_file()):
        return _as_toml(cfg.canonical()).encode()
    raw = tomllib.loads(src.read_text())
    named = b"" if "name" in raw else tomli_w.dumps({"name": cfg.name}).encode()
    if not cfg.spec.folder:
        return named + src.read_bytes()
    raw = {"name": cfg.name, **raw}
    raw["model"]["path"] = cfg.spec.folder
    return (f"# {src.name} as swept, its model.path made absolute\n"
            + tomli_w.dumps(raw)).encode()


def _as_toml(d: dict) -> str:
    import tomli_w
    return tomli_w.dumps({k: list(v) if isinstance(v, tuple) else v for k, v in d.items()})
