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
from functools import cache
from pathlib import Path

import numpy as np
import pandas as pd

from stepzoo import environment
from stepzoo.bench import metrics, sweep_folder
from stepzoo.bench.timing import COLUMNS as TIMING_COLUMNS, per_step
from stepzoo.errors import UsageError
from stepzoo.output import atomic_write, to_json, write_file
from stepzoo.results_folder import writing
from stepzoo.bench.sweep_config import SweepConfig, check_workload

REF_WINDOW = 64        # output times per reference call: its cost per step grows with them
TRAJ_SAMPLES = 200     # reference samples of the figure trajectory
TABLES = ("runs", "limits", "eigenvalues", "trajectories", "timing")
SORT = {"runs": ["method", "h", "point"], "limits": ["method", "point"],
        "eigenvalues": ["point", "lam_re", "lam_im"], "trajectories": ["method", "h", "t"],
        "timing": ["chunk"]}
STATES = ("X", "Y", "psi", "vy", "r")
RUN_COLUMNS = ["method", "h", "point", "vx", "delta", "stable", "blowup_t",
               *[f"err_{s}" for s in STATES], "err_pos", "err_final", "evals_per_s",
               *TIMING_COLUMNS, "n_steps", "ref_ok"]


# ---- chunks -----------------------------------------------------------------------------

def n_blocks(cfg: SweepConfig) -> int:
    return -(-len(cfg.points) // cfg.points_per_chunk)


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
    started = time.perf_counter()
    work = _Work(cfg, int(block), {} if cache_ is None else cache_)
    tables = work.reference_chunk() if kind == "reference" else work.method_chunk(kind)
    work.timing.update(chunk=chunk_id, method=kind, total_s=time.perf_counter() - started)
    tables["timing"] = pd.DataFrame([work.timing])
    return tables


@cache
def _batched_reference(f, rtol, atol):
    """The adaptive reference, jitted and vmapped over lanes (one compilation per model)."""
    import jax
    from stepzoo.integrators.reference import reference
    return jax.jit(jax.vmap(lambda x0, u, p, ts: reference(f, x0, u, p, ts, rtol, atol),
                            in_axes=(0, 0, 0, None)))


class _Work:
    """One block of operating points as a fixed-size batch of lanes (the last block is padded
    by repeating its last point, so every block of a method shares one compilation)."""

    def __init__(self, cfg: SweepConfig, block: int, ref_cache: dict):
        from stepzoo import dynamics
        from stepzoo.dynamics.linear import lateral_matrix
        self.cfg, self.block, self.ref_cache = cfg, block, ref_cache
        self.model = dynamics.model(cfg.model)
        pts = cfg.points
        size = min(cfg.points_per_chunk, len(pts))
        first = block * cfg.points_per_chunk
        self.ids = list(range(first, min(first + size, len(pts))))
        self.n_real = len(self.ids)
        lanes = self.ids + [self.ids[-1]] * (size - self.n_real)
        self.vx = np.array([pts[i][0] for i in lanes])
        self.delta = np.array([pts[i][1] for i in lanes])
        self.phys = dynamics.physical(cfg.vehicle)
        mats = [lateral_matrix(v, d, self.phys) for v, d in zip(self.vx, self.delta)]
        self.A = np.array([np.asarray(a) for a, _ in mats])
        self.b = np.array([np.asarray(b) for _, b in mats])
        self.max_steps = max(round(cfg.horizon / cfg.hs[0]), cfg.stab_steps)
        self.timing = dict(compile_s=0.0, ref_compile_s=0.0, reference_s=0.0,
                           integration_s=0.0, stability_s=0.0, metrics_s=0.0)

    # -- batched calls ---------------------------------------------------------------------
    def _arrays(self, vx, delta):
        import jax.numpy as jnp
        ps = [self.model.params(self.cfg.vehicle, v) for v in vx]
        p = {k: jnp.asarray([q[k] for q in ps]) for k in ps[0]}
        return p, jnp.asarray(delta)[:, None]

    def integrate(self, meth, x0, h, n, vx=None, delta=None):
        """(x (B, n+1, 5), evals (B,), wall s) of n steps of h (scalar or (B,)) [s]."""
        import jax.numpy as jnp
        from stepzoo.integrators import integrate_batch
        vx = self.vx if vx is None else vx
        p, u = self._arrays(vx, self.delta if delta is None else delta)
        hb = jnp.broadcast_to(jnp.asarray(h, float), (len(vx),))
        t0 = time.perf_counter()
        tr = integrate_batch(meth, self.model.rhs, jnp.asarray(x0), u, p, hb, jnp.asarray(n),
                             max_steps=self.max_steps)
        x = np.asarray(tr.x.block_until_ready())[:, : n + 1]
        return x, np.asarray(tr.evals), time.perf_counter() - t0

    def compile(self, meth):
        """Compile (or find compiled) the method's batched driver; charged to compile_s."""
        self.timing["compile_s"] += self.integrate(meth, self.x0_accuracy(), self.cfg.hs[0], 1)[2]

    def reference(self, h, n, vx=None, delta=None):
        """(B, n+1, 5): the reference at t = k h, k = 0..n, in windows of REF_WINDOW steps."""
        import jax.numpy as jnp
        cfg = self.cfg
        vx = self.vx if vx is None else vx
        fn = _batched_reference(self.model.rhs, cfg.rtol, cfg.atol)
        p, u = self._arrays(vx, self.delta if delta is None else delta)
        if "compiled" not in self.ref_cache:
            t0 = time.perf_counter()
            fn(jnp.asarray(self.x0_accuracy()), u, p, jnp.zeros(REF_WINDOW + 1)).x \
                .block_until_ready()
            self.timing["ref_compile_s"] += time.perf_counter() - t0
            self.ref_cache["compiled"] = True
        t0 = time.perf_counter()
        ts = h * np.arange(n + 1)
        out = np.empty((len(vx), n + 1, 5))
        out[:, 0] = self.x0_accuracy()
        ok = np.ones(len(vx), bool)
        for j in range(0, n, REF_WINDOW):
            window = ts[j: j + REF_WINDOW + 1]
            padded = np.concatenate([window, np.full(REF_WINDOW + 1 - len(window), window[-1])])
            ref = fn(jnp.asarray(out[:, j]), u, p, jnp.asarray(padded))
            out[:, j: j + len(window)] = np.asarray(ref.x)[:, : len(window)]
            ok &= np.asarray(ref.success)
        self.timing["reference_s"] += time.perf_counter() - t0
        return out, ok

    def x0_accuracy(self):
        return np.tile(np.asarray(self.cfg.x0, float), (len(self.vx), 1))

    def x0_stability(self):
        x0 = self.x0_accuracy()
        x0[:, 3:5] = [metrics.perturbed_lateral(A, b, self.cfg.perturbation)
                      for A, b in zip(self.A, self.b)]
        return x0

    def stable(self, meth, h):
        """(stable (B,), blow-up time [s] or NaN) of the stability runs at step(s) h."""
        t0 = time.perf_counter()
        h = np.broadcast_to(np.asarray(h, float), (len(self.vx),))
        x, _, _ = self.integrate(meth, self.x0_stability(), h, self.cfg.stab_steps)
        frames = [metrics.modal_frame(A, b) for A, b in zip(self.A, self.b)]
        eq = np.array([f[0] for f in frames])
        Vinv = np.array([f[2] for f in frames])
        k = metrics.blowup_steps(x[:, :, 3:5], eq, Vinv, self.cfg.growth)
        self.timing["stability_s"] += time.perf_counter() - t0
        return k < 0, np.where(k < 0, np.nan, k * h)

    # -- chunks ------------------------------------------------------------------------------
    def reference_chunk(self) -> dict:
        from stepzoo.dynamics.linear import lateral_eigenvalues
        rows = []
        for i in self.ids:
            vx, delta = self.cfg.points[i]
            ev = np.asarray(lateral_eigenvalues(vx, delta, self.phys))
            for lam in sorted(ev, key=lambda z: (z.real, z.imag)):
                rows.append(dict(point=i, vx=vx, delta=delta, lam_re=float(lam.real),
                                 lam_im=float(lam.imag)))
        traj = pd.DataFrame()
        if self.block == 0:
            tvx, tdelta = self.cfg.traj_point
            dt = self.cfg.horizon / TRAJ_SAMPLES
            lanes = len(self.vx)
            ref, _ = self.reference(dt, TRAJ_SAMPLES, np.full(lanes, tvx), np.full(lanes, tdelta))
            traj = _trajectory_rows("reference", dt, dt * np.arange(TRAJ_SAMPLES + 1), ref[0],
                                    False)
        return {"eigenvalues": pd.DataFrame(rows), "trajectories": traj}

    def method_chunk(self, name: str) -> dict:
        from stepzoo.integrators import method
        from stepzoo.integrators.stability import max_stable_step
        cfg, meth = self.cfg, method(name)
        self.compile(meth)
        runs = self._accuracy_runs(meth)
        grid_stable = np.empty((len(cfg.hs), len(self.vx)), bool)
        for j, h in enumerate(cfg.hs):
            grid_stable[j], blowup_t = self.stable(meth, h)
            runs[j]["stable"], runs[j]["blowup_t"] = grid_stable[j], blowup_t
        h_meas = self.measured_limits(meth, grid_stable)

        t0 = time.perf_counter()
        runs_df = pd.concat([pd.DataFrame(r) for r in runs], ignore_index=True)
        runs_df = runs_df.drop_duplicates(["h", "point"])[RUN_COLUMNS]   # padded lanes repeat
        limits = []
        for lane, i in enumerate(self.ids):
            rows = runs_df[(runs_df["point"] == i) & runs_df["stable"]]
            h_pred = max_stable_step(meth, np.linalg.eigvals(self.A[lane]))
            limits.append(dict(
                method=name, point=i, vx=self.vx[lane], delta=self.delta[lane], h_pred=h_pred,
                h_meas=h_meas[lane], ratio=_ratio(h_meas[lane], h_pred),
                order_declared=meth.order,
                # Yaw-rate error: position errors stay pre-asymptotic down to round-off
                # for methods with small leading error terms (dopri5).
                order_fit=metrics.order_fit(rows["h"], rows["err_r"], cfg.rtol, cfg.atol,
                                            self.r_scale[lane]),
                h_probe_max=cfg.h_probe_max))
        traj = self._trajectories(meth) if self.block == 0 else pd.DataFrame()
        self.timing["metrics_s"] += time.perf_counter() - t0
        return {"runs": runs_df, "limits": pd.DataFrame(limits), "trajectories": traj}

    def _accuracy_runs(self, meth) -> list[dict]:
        """Per grid step, the columns of `runs` for every lane (stability columns to come)."""
        cfg, out = self.cfg, []
        self.r_scale = np.zeros(len(self.vx))      # [rad/s] largest reference yaw rate
        for h in cfg.hs:
            n = round(cfg.horizon / h)
            x, evals, wall = self.integrate(meth, self.x0_accuracy(), h, n)
            # Compiled already (self.compile): every round times the computation alone.
            walls = [wall] + [self.integrate(meth, self.x0_accuracy(), h, n)[2]
                              for _ in range(cfg.timing_rounds - 1)]
            self.timing["integration_s"] += sum(walls)
            key = ("accuracy", self.block, h)
            if key not in self.ref_cache:
                self.ref_cache[key] = self.reference(h, n)
            ref, ok = self.ref_cache[key]
            self.r_scale = np.maximum(self.r_scale, np.abs(ref[:, :, 4]).max(axis=1))
            t0 = time.perf_counter()
            errs = [metrics.run_errors(x[k], ref[k]) for k in range(len(self.vx))]
            col = {"method": meth.name, "h": h, "point": self.ids + [self.ids[-1]] * (
                len(self.vx) - self.n_real), "vx": self.vx, "delta": self.delta}
            for s, state in enumerate(STATES):
                col[f"err_{state}"] = [e[0][s] for e in errs]
            col["err_pos"] = [e[1] for e in errs]
            col["err_final"] = [e[2] for e in errs]
            col["evals_per_s"] = evals / (n * h)
            col.update(per_step(walls, n * len(self.vx)))
            col["n_steps"] = n
            col["ref_ok"] = ok
            self.timing["metrics_s"] += time.perf_counter() - t0
            out.append(col)
        return out

    def measured_limits(self, meth, grid_stable) -> np.ndarray:
        """Largest stable step [s] per lane: bracketed by the grid (extended by doubling up
        to h_probe_max, or halving below the grid), then bisected. inf: no blow-up up to
        h_probe_max; 0: unstable even at the smallest probe."""
        cfg, hs = self.cfg, np.asarray(self.cfg.hs)
        lanes = len(self.vx)
        lo, hi = np.full(lanes, np.nan), np.full(lanes, np.nan)
        for lane in range(lanes):
            bad = np.where(~grid_stable[:, lane])[0]
            if len(bad) and bad[0] > 0:
                lo[lane], hi[lane] = hs[bad[0] - 1], hs[bad[0]]
        up = [hs[-1] * 2.0 ** k for k in range(1, 64) if hs[-1] * 2.0 ** k < cfg.h_probe_max]
        self._ladder(meth, lo, hi, grid_stable[-1], hs[-1], up + [cfg.h_probe_max], rising=True)
        down = [hs[0] / 2.0 ** k for k in range(1, 11)]
        self._ladder(meth, lo, hi, grid_stable[0], hs[0], down, rising=False)
        lo = np.where(np.isnan(lo), np.inf, lo)        # never unstable: no finite limit found
        bracketed = np.isfinite(hi)
        found = metrics.bisect_limit(lambda h: self.stable(meth, h)[0],
                                     np.where(bracketed, lo, 1.0), np.where(bracketed, hi, 1.0),
                                     cfg.rel_tol)
        return np.where(bracketed, found, lo)

    def _ladder(self, meth, lo, hi, last_ok, last_h, probes, rising):
        """Probe beyond one end of the grid for lanes the grid did not bracket there."""
        need = np.isnan(lo) & (last_ok if rising else ~last_ok)
        prev = np.full(len(lo), last_h)
        for h in probes:
            if not need.any():
                return
            ok, _ = self.stable(meth, h)
            found = need & (~ok if rising else ok)
            if rising:
                lo[found], hi[found] = prev[found], h
            else:
                lo[found], hi[found] = h, prev[found]
            need &= ~found
            prev[:] = h
        if not rising:
            lo[need], hi[need] = 0.0, np.inf     # unstable at every probe: limit 0
        else:
            hi[need] = np.inf

    def _trajectories(self, meth) -> pd.DataFrame:
        """Figure runs at the trajectory point: fractions of the predicted limit (of the
        largest grid step for A-stable methods) and one past it, from the accuracy x0."""
        from stepzoo.dynamics.linear import lateral_eigenvalues
        from stepzoo.integrators.stability import max_stable_step
        cfg = self.cfg
        tvx, tdelta = cfg.traj_point
        limit = max_stable_step(meth, np.asarray(
            lateral_eigenvalues(tvx, tdelta, self.phys)))
        base = limit if math.isfinite(limit) else cfg.hs[-1]
        hs = [max(f * base, cfg.hs[0]) for f in cfg.traj_fractions]
        past = [False] * len(hs)
        if math.isfinite(limit):
            hs.append(cfg.traj_past_limit * limit)
            past.append(True)
        frames, lanes = [], len(self.vx)
        for start in range(0, len(hs), lanes):
            chunk = hs[start: start + lanes]
            h = np.array(chunk + [chunk[-1]] * (lanes - len(chunk)))
            n = min(self.max_steps, math.ceil(cfg.horizon / h.min() - 1e-9))
            x, _, _ = self.integrate(meth, self.x0_accuracy(), h, n, np.full(lanes, tvx),
                                     np.full(lanes, tdelta))
            for k, hk in enumerate(chunk):
                keep = min(n, math.floor(cfg.horizon / hk + 1e-9)) + 1
                frames.append(_trajectory_rows(meth.name, hk, hk * np.arange(keep),
                                               x[k, :keep], past[start + k]))
        return pd.concat(frames, ignore_index=True)


def _trajectory_rows(name, h, t, x, past_limit) -> pd.DataFrame:
    df = pd.DataFrame(x, columns=list(STATES))
    df.insert(0, "t", t)
    df.insert(0, "h", float(h))
    df.insert(0, "method", name)
    df["past_limit"] = past_limit
    return df


def _ratio(meas, pred):
    if math.isinf(meas) and math.isinf(pred):
        return float("nan")                   # both unbounded: no ratio to speak of
    return meas / pred


# ---- the results folder -----------------------------------------------------------------

def run_sweep(cfg: SweepConfig, out, resume=False, overwrite=False, progress=True,
              on_chunk=None, runner=None) -> dict:
    """Compute every missing chunk of `cfg` into `out` and write the tables; returns the
    manifest. `on_chunk(chunk_id)` is called after each chunk is safely on disk. `runner(cfg,
    chunk_ids)`, if given, computes the chunks elsewhere (`bench.distributed`) and yields
    (chunk id, tables) as they finish; by default they are computed here, in order. The
    folder is locked meanwhile: a second sweep into it is refused (`results_folder`)."""
    sweep_folder.check_flags(resume, overwrite)
    check_workload(cfg)
    with writing(out, "sweep"):
        return _fill(cfg, Path(out), resume, overwrite, progress, on_chunk, runner)


def _fill(cfg, out: Path, resume, overwrite, progress, on_chunk, runner) -> dict:
    from tqdm import tqdm
    started = time.perf_counter()
    chunks = out / "chunks"
    old = sweep_folder.check_start(cfg, out, resume, overwrite)
    chunks.mkdir(parents=True, exist_ok=True)
    for stale in chunks.glob(".*.tmp*"):           # a chunk cut off while being written
        shutil.rmtree(stale, ignore_errors=True)
    src = Path(cfg.source) if cfg.source else None
    atomic_write(out / "config.toml", src.read_bytes() if src and src.is_file()
                 else _as_toml(cfg.canonical()))
    created = (old or {}).get("created") or datetime.now(timezone.utc).isoformat(
        timespec="seconds")
    created = (created, environment.now())      # the first call's start, and this call's
    ids = chunk_ids(cfg)
    done = [c for c in ids if (chunks / c).is_dir()]
    _write_manifest(cfg, out, created, done, None, complete=False)
    ref_cache: dict = {}
    todo = [c for c in ids if c not in done]
    computed = runner(cfg, todo) if runner is not None else \
        ((cid, compute_chunk(cfg, cid, ref_cache)) for cid in todo)
    for cid, tables in tqdm(computed, total=len(todo), desc=f"sweep {cfg.name}", unit="chunk",
                            file=sys.stderr, disable=not progress):
        _write_chunk(chunks, cid, tables)
        done.append(cid)
        _write_manifest(cfg, out, created, [c for c in ids if c in done], None, complete=False)
        if on_chunk is not None:
            on_chunk(cid)
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
    for name in ("runs", "limits", "eigenvalues", "trajectories", "summary"):
        atomic_write(out / f"{name}.parquet", _parquet(tables[name]))
    for name in ("limits", "summary"):
        atomic_write(out / f"{name}.csv", tables[name].to_csv(index=False))
    timing = _timing(tables["timing"], time.perf_counter() - t0, time.perf_counter() - started)
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
    parts = {name: [] for name in TABLES}
    for cid in chunk_ids(cfg):
        for name in TABLES:
            path = chunks / cid / f"{name}.parquet"
            if path.is_file():
                df = pd.read_parquet(path)
                if len(df):
                    parts[name].append(df)
    tables = {}
    for name in TABLES:
        df = pd.concat(parts[name], ignore_index=True) if parts[name] else pd.DataFrame()
        tables[name] = df.sort_values(SORT[name], kind="stable", ignore_index=True) \
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
        ratios = lim["ratio"].to_numpy(float)
        finite = ratios[np.isfinite(ratios) & (ratios > 0)]
        worst = finite[np.argmax(np.abs(np.log(finite)))] if len(finite) else np.nan
        r = runs[runs["method"] == name]
        rows.append(dict(
            method=name, family=m.family, order_declared=m.order,
            order_fit_median=float(lim["order_fit"].median()),
            order_fit_min=float(lim["order_fit"].min()),
            order_fit_max=float(lim["order_fit"].max()),
            real_interval=real, imag_interval=imag,
            h_meas_min=float(lim["h_meas"].min()), h_pred_min=float(lim["h_pred"].min()),
            worst_ratio=float(worst), implicit=m.implicit,
            evals_per_step=float((r["evals_per_s"] * r["h"]).median()),
            points=int(lim["point"].nunique())))
    return pd.DataFrame(rows)


def _timing(per_chunk: pd.DataFrame, assemble_s: float, wall_s: float) -> dict:
    compile_s = per_chunk.groupby("method")["compile_s"].sum().drop("reference", errors="ignore")
    out = {"compile_s": {k: round(float(v), 3) for k, v in compile_s.items()}}
    out["compile_s"]["reference"] = round(float(per_chunk["ref_compile_s"].sum()), 3)
    for key in ("reference_s", "integration_s", "stability_s", "metrics_s"):
        out[key] = round(float(per_chunk[key].sum()), 3)
    out["metrics_s"] = round(out["metrics_s"] + assemble_s, 3)
    out["total_s"] = round(float(per_chunk["total_s"].sum()) + assemble_s, 3)
    out["wall_s"] = round(wall_s, 3)
    return out


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
        "blowup_rule": metrics.BLOWUP_RULE,
        "stability": {"steps": cfg.stab_steps, "growth": cfg.growth,
                      "perturbation": cfg.perturbation, "h_probe_max_s": cfg.h_probe_max,
                      "bisection_rel_tol": cfg.rel_tol},
        "order_fit": (f"slope of log err_r on log h over the {metrics.ORDER_POINTS} finest "
                      f"stable steps with {metrics.FLOOR_FACTOR:g} * (atol + rtol * max|r|) "
                      f"< err_r < {metrics.ERR_CEIL:g} rad/s; NaN where fewer than 3 qualify "
                      "(a run from rest at zero steer has no error)"),
        "trajectory_point": {"vx": cfg.traj_point[0], "delta": cfg.traj_point[1]},
        "horizon_s": cfg.horizon, "vehicle": cfg.vehicle, "model": cfg.model,
        "stepzoo_version": ver, "timing_rounds": cfg.timing_rounds,
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


def _as_toml(d: dict) -> str:
    import tomli_w
    return tomli_w.dumps({k: list(v) if isinstance(v, tuple) else v for k, v in d.items()})
