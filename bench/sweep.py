"""The sweep engine: every (method, h, operating point) of a config, in chunks of one method
by one block of points. `compute_chunk(config, chunk_id)` is pure (a Dask worker can call
it); `run_sweep` writes each chunk as it finishes, resumes, and concatenates the tables."""
from __future__ import annotations

import math
import os
import shutil
import sys
import time
from contextlib import contextmanager
from datetime import datetime, timezone
from functools import cache
from pathlib import Path

import numpy as np
import pandas as pd

from stepzoo import environment
from stepzoo.bench import (frozen, jit_clock, metrics, model_nan, nonsmooth, schema,
                           sweep_folder)
from stepzoo.bench.timing import CALIBRATION_STEPS, busiest_per_step, calibrated
from stepzoo.bench.timing import RULE as TIMING_RULE
from stepzoo.errors import UsageError
from stepzoo.output import atomic_write, to_json, write_file
from stepzoo.results_folder import claim
from stepzoo.bench.sweep_config import ESTIMATES, SweepConfig, check_workload, default_solver

REF_WINDOW = 64        # output times per reference call: its cost per step grows with them
TRAJ_SAMPLES = 200     # reference samples of the figure trajectory
TRAJ_ROWS = 2000       # states kept of one figure run (evenly spread over it)
ALONG_SAMPLES = 50     # reference samples whose Jacobians predict the stable step (divides
                       # TRAJ_SAMPLES: the figure trajectory's prediction reuses the shape)
NARROWING = ("the grid's bracket [lo, hi] (lo stable, hi not) shrinks to hi / lo <= 1 + "
             "rel_tol; the first round probes at h_pred (and rel_tol apart around it when the "
             "block's call has room), later ones gallop away from it, then split the bracket "
             "evenly; h_meas is lo, so ratio 1 means a limit in [h_pred, h_pred (1 + rel_tol))")

REFERENCE_KINDS = {
    "exact": "the model's closed form (reference.exact)",
    "scipy": "SciPy's {} at reference.rtol/atol, per distinct lane",
    "adaptive": "adaptive Dormand-Prince 5(4) at reference.rtol/atol, restarted every "
                f"{REF_WINDOW} output times"}


def _reference_kind(cfg: SweepConfig) -> str:
    if cfg.exact_reference:
        return "exact"
    return "adaptive" if _solver(cfg) == "dopri5" else "scipy"


def _solver(cfg: SweepConfig) -> str:
    """The reference's solver: reference.solver, else the model's default."""
    return cfg.ref_solver or default_solver(cfg.spec)


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


def _tile(a, k: int):
    """Each lane's row repeated k times in a row: (B, ...) -> (B k, ...)."""
    return np.repeat(np.asarray(a), k, axis=0)


class _Work:
    """One block of operating points as a fixed-size batch of lanes (the last block is padded
    by repeating its last point, so every block of a method shares one compilation)."""

    def __init__(self, cfg: SweepConfig, block: int, ref_cache: dict):
        self.cfg, self.block, self.ref_cache = cfg, block, ref_cache
        self.spec = cfg.spec
        pts = cfg.points
        size = min(cfg.points_per_chunk, len(pts))
        first = block * cfg.points_per_chunk
        self.ids = list(range(first, min(first + size, len(pts))))
        self.n_real = len(self.ids)
        self.lanes = self.ids + [self.ids[-1]] * (size - self.n_real)
        self.values = np.array([pts[i] for i in self.lanes], float).reshape(size, -1)
        self.x0, self.u, self.p = self.spec.arrays([pts[i] for i in self.lanes])
        self.max_steps = max(round(cfg.horizon / cfg.hs[0]), cfg.stab_steps)
        self.timing = dict(compile_s=0.0, ref_compile_s=0.0, reference_s=0.0,
                           integration_s=0.0, stability_s=0.0, metrics_s=0.0)

    def point_columns(self) -> dict:
        return {var: self.values[:, j] for j, var in enumerate(self.spec.variables)}

    # -- batched calls ---------------------------------------------------------------------
    def integrate(self, meth, x0, u, p, h, n):
        """(x (B, n+1, d), evals (B,), converged (B,), run s) of n steps of h [s]; the run
        time leaves out JAX's compiling, which goes to timing's compile_s."""
        import jax.numpy as jnp
        from stepzoo.integrators import integrate_batch
        hb = jnp.broadcast_to(jnp.asarray(h, float), (len(x0),))
        with jit_clock.split() as took:
            tr = integrate_batch(meth, self.spec.rhs, jnp.asarray(x0), jnp.asarray(u),
                                 {k: jnp.asarray(v) for k, v in p.items()}, hb, jnp.asarray(n),
                                 max_steps=self.max_steps)
            x = np.asarray(tr.x.block_until_ready())[:, : n + 1]
        self.timing["compile_s"] += took["compile"]
        converged = np.asarray(tr.converged, bool)
        return x, np.asarray(tr.evals), converged, took["wall"] - took["compile"]

    @contextmanager
    def clock(self, key):
        """Charges the block's wall time to timing[key], less JAX's compiling in it, which goes
        to ref_compile_s (for references) or compile_s. Blocks that call `integrate` are
        not clocked: it charges its own."""
        with jit_clock.split() as took:
            yield
        self.timing[key] += took["wall"] - took["compile"]
        self.timing["ref_compile_s" if key == "reference_s" else "compile_s"] += took["compile"]

    def reference(self, h, n, x0=None, u=None, p=None):
        """((B, n+1, d) the reference at t = k h, k = 0..n, in windows of REF_WINDOW steps,
        ok (B,)); the block's lanes unless x0, u, p are given."""
        import jax.numpy as jnp
        cfg = self.cfg
        x0, u, p = (self.x0, self.u, self.p) if x0 is None else (x0, u, p)
        if cfg.exact_reference:
            return self._exact_reference(h, n, len(x0))
        if _reference_kind(cfg) == "scipy":
            return self._scipy_reference(h, n, x0, u, p)
        fn = _batched_reference(self.spec.rhs, cfg.rtol, cfg.atol)
        uj, pj = jnp.asarray(u), {k: jnp.asarray(v) for k, v in p.items()}
        ts = h * np.arange(n + 1)
        out = np.empty((len(x0), n + 1, len(self.spec.states)))
        out[:, 0] = x0
        ok = np.ones(len(x0), bool)
        with self.clock("reference_s"):
            for j in range(0, n, REF_WINDOW):
                window = ts[j: j + REF_WINDOW + 1]
                padded = np.concatenate([window,
                                         np.full(REF_WINDOW + 1 - len(window), window[-1])])
                ref = fn(jnp.asarray(out[:, j]), uj, pj, jnp.asarray(padded))
                out[:, j: j + len(window)] = np.asarray(ref.x)[:, : len(window)]
                ok &= np.asarray(ref.success)
        return out, ok

    def _exact_reference(self, h, n, lanes):
        """The model's closed form at t = k h [s], k = 0..n, in each of the lanes (the config
        keeps every lane at the model's own problem, which the closed form solves)."""
        from stepzoo import dynamics
        with self.clock("reference_s"):
            x = dynamics.MODELS[self.spec.name].exact(h * np.arange(n + 1))
        return np.broadcast_to(np.asarray(x, float), (lanes, n + 1, len(x[0]))).copy(), \
            np.ones(lanes, bool)

    def _scipy_reference(self, h, n, x0, u, p):
        """A reference by SciPy's solve_ivp (`solutions.solve`, the config's solver) per
        distinct lane at the config's tolerances; a lane it fails on is NaN, ref_ok False."""
        from stepzoo.dynamics.solutions import solve
        ts = h * np.arange(n + 1)
        out = np.full((len(x0), n + 1, len(self.spec.states)), np.nan)
        ok = np.zeros(len(x0), bool)
        done = {}
        with self.clock("reference_s"):
            for b in range(len(x0)):
                key = (tuple(x0[b]), tuple(u[b]), tuple(v[b] for v in p.values()))
                if key not in done:
                    try:
                        done[key] = solve(self.spec.rhs, x0[b], u[b],
                                          {k: v[b] for k, v in p.items()}, ts,
                                          method=_solver(self.cfg), rtol=self.cfg.rtol,
                                          atol=self.cfg.atol)
                    except RuntimeError:
                        done[key] = None
                if done[key] is not None:
                    out[b], ok[b] = done[key], True
        return out, ok

    def _cached(self, key, make):
        key = (key, self.block)
        if key not in self.ref_cache:
            self.ref_cache[key] = make()
        return self.ref_cache[key]

    # -- prediction ------------------------------------------------------------------------
    def along(self):
        """(times (T,), reference states (B, T, d), eigenvalues (B, T, d), Jacobians) along
        each lane's reference over the horizon: the frozen Jacobians that predict the step."""
        def make():
            dt = self.cfg.horizon / ALONG_SAMPLES
            ts = dt * np.arange(ALONG_SAMPLES + 1)
            xs, _ = self.reference(dt, ALONG_SAMPLES)
            with self.clock("metrics_s"):
                jac = frozen.jacobians(self.spec.rhs, ts, xs, self.u, self.p)
            return ts, xs, frozen.eigenvalues(jac), jac
        return self._cached("along", make)

    def nonsmooth(self) -> list:
        """Per lane, where f is not smooth along its reference at the smallest grid step
        (bench.nonsmooth; none where that reference failed)."""
        def make():
            h = self.cfg.hs[0]
            n = round(self.cfg.horizon / h)
            ref, ok = self._cached(("accuracy", h), lambda: self.reference(h, n))
            with self.clock("metrics_s"):
                return nonsmooth.detect(self.spec.rhs, h * np.arange(n + 1),
                                        np.where(ok[:, None, None], ref, np.nan), self.u,
                                        self.p, self.spec.states, self.spec.inputs,
                                        self.cfg.rtol, self.cfg.atol)
        return self._cached("nonsmooth", make)

    def predicted(self, meth) -> list[tuple[float, int, int]]:
        """Per lane, (largest stable step [s], time index, eigenvalue index where it binds)
        of the method along the lane's reference (frozen.predicted_limit)."""
        lam = self.along()[2]
        with self.clock("metrics_s"):
            return [frozen.predicted_limit(meth, lam[b]) for b in range(len(self.x0))]

    def perturbation(self) -> np.ndarray:
        """(B, d) initial deviation of the stability runs: the same amount of each eigenmode
        of the Jacobian at the initial state that bounds a step (each mode scaled to size 1
        in the error norm), the sum scaled to `perturbation`; every error state alike when
        no mode bounds one."""
        jac = self.along()[3]
        out = np.zeros_like(self.x0)
        for b in range(len(self.x0)):
            # A model not finite at the start (model_nan) has no modes: every state alike.
            finite = np.isfinite(jac[b, 0]).all()
            w, V = np.linalg.eig(jac[b, 0] if finite else np.zeros_like(jac[b, 0]))
            keep = frozen.constraining(w)
            d = np.zeros(len(w))
            for j in np.where(keep)[0]:
                size = self.spec.scaled(V[:, j].real) + self.spec.scaled(V[:, j].imag)
                if np.isfinite(size) and size > 0:
                    d += V[:, j].real / size
            size = self.spec.scaled(d)
            if not (np.isfinite(size) and size > 0):
                d = np.zeros(len(w))
                d[self.spec.error_index] = self.spec.error_scales
                size = 1.0
            out[b] = self.cfg.perturbation * d / size
        return out

    @property
    def delta(self) -> np.ndarray:
        return self._cached("perturbation", self.perturbation)

    # -- stability -------------------------------------------------------------------------
    def stable(self, meth, H):
        """(stable, blow-up time [s] or NaN, converged), each (B, K), of the stability runs
        at steps H (B, K) [s], row b at lane b (see `runs_at`)."""
        return self.stable_at(meth, np.arange(len(H)), np.asarray(H, float).T)

    def stable_at(self, meth, lanes, hs):
        """`stable` of the lanes (L,) at steps hs (K,) [s], the same for each, or (K, L): the
        outcomes are (L, K). Step by step: a call then holds as few steps as it can, which
        keeps an implicit method's Newton iterations, run in lockstep over a call, as few as
        each step needs."""
        hs = np.asarray(hs, float)
        hs = np.broadcast_to(hs[:, None] if hs.ndim == 1 else hs, (len(hs), len(lanes)))
        out = self.runs_at(meth, np.tile(lanes, len(hs)), hs.ravel())
        return tuple(a.reshape(hs.shape).T for a in out)

    def runs_at(self, meth, lanes, h):
        """(stable, blow-up time [s] or NaN, converged), each (N,), of the stability runs of
        candidate steps h (N,) [s] at lanes (N,): a run from the initial state plus the
        perturbation against a run from the initial state with the same method and step. It
        blows up at the first step where their scaled distance is not finite or exceeds
        `growth` times its start; a run whose nonlinear solves failed is never stable. The
        candidates go in calls of the block's own size (the last one filled with repeats):
        the accuracy runs' compiled program serves them."""
        B, N = len(self.x0), len(h)
        ok, t_blow, conv = np.zeros(N, bool), np.full(N, np.nan), np.zeros(N, bool)
        for start in range(0, N, B):
            part = slice(start, min(start + B, N))
            m = part.stop - start
            idx, hh = np.resize(lanes[part], B), np.resize(h[part], B)
            u, p = self.u[idx], {k: v[idx] for k, v in self.p.items()}
            xa, _, ca, run_a = self.integrate(meth, self.x0[idx] + self.delta[idx], u, p, hh,
                                              self.cfg.stab_steps)
            xb, _, cb, run_b = self.integrate(meth, self.x0[idx], u, p, hh, self.cfg.stab_steps)
            t0 = time.perf_counter()
            with np.errstate(invalid="ignore", over="ignore"):
                dev = self.spec.scaled(xa[:m] - xb[:m])
                blown = ~(dev <= self.cfg.growth * dev[:, :1])
            k = np.where(blown.any(axis=1), np.argmax(blown, axis=1), -1)
            conv[part] = ca[:m] & cb[:m]
            ok[part] = (k < 0) & conv[part]
            t_blow[part] = np.where(k < 0, np.nan, k * hh[:m])
            self.timing["stability_s"] += run_a + run_b + time.perf_counter() - t0
        return ok, t_blow, conv

    def measured_limits(self, meth, grid_ok, grid_conv, pred):
        """(largest stable step [s], cause) per lane: bracketed by the grid (extended by
        doubling up to h_probe_max, or halving below it), then narrowed to rel_tol, starting
        at the predicted limit pred [s] of each lane (see `_candidates`). inf: nothing failed
        up to h_probe_max (one probe there where pred is inf, the doubling ladder where that
        fails or pred is finite); 0: unstable even at the smallest probe. The cause says what
        failed just above the limit: 'unstable', 'solver failed' or 'none'."""
        cfg, hs = self.cfg, np.asarray(self.cfg.hs)
        B = len(self.x0)
        lo, hi = np.full(B, np.nan), np.full(B, np.nan)
        cause = np.full(B, "none", object)
        bad = ~grid_ok
        first = np.argmax(bad, axis=1)
        inner = bad.any(axis=1) & (first > 0)
        lo[inner], hi[inner] = hs[first[inner] - 1], hs[first[inner]]
        cause[inner] = np.where(grid_conv[inner, first[inner]], "unstable", "solver failed")

        up = [hs[-1] * 2.0 ** k for k in range(1, 64) if hs[-1] * 2.0 ** k < cfg.h_probe_max]
        rising = np.where(np.isnan(lo) & grid_ok[:, -1])[0]
        # Where nothing is predicted to bound the step, one probe at h_probe_max says so; the
        # ladder climbs only to the lanes that fail there, where the prediction is off.
        unbounded = rising[np.isinf(pred[rising])]
        if len(unbounded):
            ok, _, _ = self.stable_at(meth, unbounded, np.array([cfg.h_probe_max]))
            lo[unbounded[ok[:, 0]]] = hi[unbounded[ok[:, 0]]] = np.inf
            rising = np.setdiff1d(rising, unbounded[ok[:, 0]])
        if len(rising):
            ladder = np.array([*up, cfg.h_probe_max])
            ok, _, conv = self.stable_at(meth, rising, ladder)
            for r, b in enumerate(rising):
                fails = np.where(~ok[r])[0]
                if len(fails):
                    j = fails[0]
                    lo[b], hi[b] = ladder[j - 1] if j else hs[-1], ladder[j]
                    cause[b] = "unstable" if conv[r, j] else "solver failed"
                else:
                    lo[b] = hi[b] = np.inf
        falling = np.where(np.isnan(lo))[0]
        if len(falling):
            ladder = hs[0] / 2.0 ** np.arange(1, 11)
            ok, _, _ = self.stable_at(meth, falling, ladder)
            for r, b in enumerate(falling):
                fine = np.where(ok[r])[0]
                cause[b] = "unstable" if grid_conv[b, 0] else "solver failed"
                if len(fine):
                    j = fine[0]
                    lo[b], hi[b] = ladder[j], ladder[j - 1] if j else hs[0]
                else:
                    lo[b] = hi[b] = 0.0
        if (np.isfinite(hi) & (hi > lo * (1 + cfg.rel_tol))).any():
            self.narrow(meth, lo, hi, cause, pred)
        return lo, cause

    def narrow(self, meth, lo, hi, cause, pred):
        """Shrinks each finite bracket [lo, hi] [s] (lo stable, hi not) in place until hi / lo
        <= 1 + rel_tol, guided by the predicted limits pred [s]. Every round fills one call of
        the block's size: the lanes still busy share its slots, so the last few get several
        candidates each."""
        tau = math.log1p(self.cfg.rel_tol)
        with np.errstate(invalid="ignore", divide="ignore"):
            guess = np.where((pred > lo) & (pred < hi), np.log(pred), np.nan)
        rounds = np.zeros(len(lo), int)

        def busy():
            with np.errstate(invalid="ignore"):
                return np.where(np.isfinite(hi) & (np.log(hi / lo) > tau * (1 + 1e-9)))[0]

        while len(todo := busy()):
            share = len(self.x0) // len(todo)
            lanes, cands = [], []
            for b in todo:
                # The gallop away from the guess: tau in the second round, doubling after.
                c = np.exp(_candidates(math.log(lo[b]), math.log(hi[b]), guess[b],
                                       tau * 2.0 ** (rounds[b] - 1), share, rounds[b] == 0, tau))
                lanes += [b] * len(c)
                cands.append(c)
            ok, _, conv = self.runs_at(meth, np.array(lanes), np.concatenate(cands))
            at = 0
            for b, c in zip(todo, cands):
                ok_b, conv_b = ok[at: at + len(c)], conv[at: at + len(c)]
                at += len(c)
                fails = np.where(~ok_b)[0]
                if len(fails):
                    j = fails[0]
                    hi[b] = c[j]
                    cause[b] = "unstable" if conv_b[j] else "solver failed"
                    if j:
                        lo[b] = c[j - 1]
                else:
                    lo[b] = c[-1]
            rounds[todo] += 1

    # -- chunks ------------------------------------------------------------------------------
    def reference_chunk(self) -> dict:
        lam = self.along()[2]
        rows = []
        for lane, i in enumerate(self.ids):
            ev = lam[lane, 0]
            keep = frozen.constraining(ev) | (np.abs(ev) > frozen.REL_ZERO
                                              * np.nanmax(np.abs(ev), initial=0.0))
            for z in sorted(ev[keep], key=lambda z: (z.real, z.imag)):
                rows.append(dict(point=i, **{v: self.values[lane, j] for j, v in
                                             enumerate(self.spec.variables)},
                                 lam_re=float(z.real), lam_im=float(z.imag)))
        traj = pd.DataFrame()
        if self.block == 0:
            t, ref = self.trajectory_reference()
            traj = _trajectory_rows(self.spec, "reference", t[1] - t[0], t, ref, False)
        return {"eigenvalues": pd.DataFrame(rows, columns=schema.eigen_columns(
            self.spec.variables)), "trajectories": traj}

    def trajectory_reference(self):
        """(times (TRAJ_SAMPLES+1,), reference states) at the trajectory point."""
        def make():
            x0, u, p = self._traj_lanes()
            dt = self.cfg.horizon / TRAJ_SAMPLES
            ref, _ = self.reference(dt, TRAJ_SAMPLES, x0, u, p)
            return dt * np.arange(TRAJ_SAMPLES + 1), ref[0]
        return self._cached("trajectory", make)

    def _traj_lanes(self):
        """The trajectory point in every lane (the batch keeps its compiled shape)."""
        x0, u, p = self.spec.arrays([self.cfg.traj_point] * len(self.x0))
        return x0, u, p

    def method_chunk(self, name: str) -> dict:
        cfg, meth = self.cfg, self.cfg.method(name)
        # Compiles the one program of the chunk's runs, accuracy and stability alike, so
        # that the timed accuracy rounds below time the computation alone.
        self.integrate(meth, self.x0, self.u, self.p, cfg.hs[0], 1)
        runs, err_scale = self._accuracy_runs(meth)
        grid_ok, blowup_t, grid_conv = self.stable(
            meth, np.tile(np.asarray(cfg.hs), (len(self.x0), 1)))
        for j, col in enumerate(runs):
            # The order fit reads the accuracy run alone: a step the stability test calls
            # unstable (the perturbation grew, as it does in a growing exact solution) still
            # has a meaningful error when its own solves converged against a good reference.
            col["fit"] = col["converged"] & col["ref_ok"]
            col["stable"], col["blowup_t"] = grid_ok[:, j], blowup_t[:, j]
            col["converged"] = col["converged"] & grid_conv[:, j]
            col["stable"] &= col["converged"]
        predicted = self.predicted(meth)
        h_meas, cause = self.measured_limits(meth, grid_ok, grid_conv,
                                             np.array([p[0] for p in predicted]))

        ts, xs, lam, _ = self.along()
        events = self.nonsmooth()
        with self.clock("metrics_s"):
            columns = schema.run_columns(self.spec.variables, self.spec.states, self.spec.vehicle)
            every = pd.concat([pd.DataFrame(r) for r in runs], ignore_index=True)
            every = every.drop_duplicates(["h", "point"])             # padded lanes repeat
            runs_df = every[columns]
            limits = []
            for lane, i in enumerate(self.ids):
                rows = every[(every["point"] == i) & every["fit"]]
                fit = metrics.order_fit(rows["h"], rows["err"], cfg.rtol, cfg.atol,
                                        err_scale[lane])
                rho = float(np.nanmax(np.abs(lam[lane]), initial=0.0))
                h_pred, k, j = predicted[lane]
                bind = lam[lane, k, j] if k >= 0 else complex(np.nan, np.nan)
                limits.append(dict(
                    method=name, point=i, **{v: self.values[lane, c] for c, v in
                                             enumerate(self.spec.variables)},
                    h_pred=h_pred, h_meas=h_meas[lane], ratio=_ratio(h_meas[lane], h_pred),
                    order_declared=meth.order,
                    **fit.columns(), rho_max=rho, order_h_rho=fit.h_min * rho,
                    h_probe_max=cfg.h_probe_max, t_bind=ts[k] if k >= 0 else np.nan,
                    lam_re_bind=bind.real, lam_im_bind=bind.imag, limit_cause=cause[lane],
                    **{f"bind_{s}": xs[lane, k, c] if k >= 0 else np.nan
                       for c, s in enumerate(self.spec.states)}, **events[lane].columns()))
        model_nan.record(limits, model_nan.lane_times(self))
        traj = self._trajectories(meth) if self.block == 0 else pd.DataFrame()
        limits_df = pd.DataFrame(limits, columns=schema.limit_columns(self.spec.variables,
                                                                      self.spec.states))
        return {"runs": runs_df, "limits": limits_df, "trajectories": traj}

    def _accuracy_runs(self, meth) -> tuple[list[dict], np.ndarray]:
        """Per grid step, the columns of `runs` for every lane (stability columns to come),
        and per lane the largest scaled size of the reference's error states. Each run is
        integrated once; its timing columns are the method's calibration (`_calibrate`)."""
        cfg, spec, out = self.cfg, self.spec, []
        scale = np.zeros(len(self.x0))
        walls, work = [], []
        for h in cfg.hs:
            n = round(cfg.horizon / h)
            # Compiled already (method_chunk): the wall time is the computation's alone.
            x, evals, conv, wall = self.integrate(meth, self.x0, self.u, self.p, h, n)
            self.timing["integration_s"] += wall
            walls.append(wall)
            ref, ok = self._cached(("accuracy", h), lambda: self.reference(h, n))
            t0 = time.perf_counter()
            scale = np.maximum(scale, spec.scaled(ref).max(axis=1))
            col = {"method": meth.name, "h": h, "point": self.lanes, **self.point_columns()}
            with np.errstate(invalid="ignore", over="ignore"):
                d = np.abs(x - ref)
            d = np.where(np.isfinite(d), d, np.inf)
            for s, state in enumerate(spec.states):
                col[f"err_{state}"] = d[:, :, s].max(axis=1)
            if spec.vehicle:
                pos = np.hypot(d[:, :, spec.states.index("X")], d[:, :, spec.states.index("Y")])
                col["err_pos"], col["err_final"] = pos.max(axis=1), pos[:, -1]
            col["err"] = metrics.run_error(spec, x, ref, cfg.error_estimate)
            col["evals_per_s"] = evals / (n * h)
            col["n_steps"] = n
            col["ref_ok"] = ok
            col["converged"] = conv
            col["evals"] = evals
            work.append(busiest_per_step(evals, n))
            self.timing["metrics_s"] += time.perf_counter() - t0
            out.append(col)
        cal, j = self._calibrate(meth, walls)
        for col, w in zip(out, work):
            col.update(calibrated(cal, out[j]["n_steps"] * len(self.x0), w / work[j]))
            col["time_s"] = col["time_per_step_s"] * col["n_steps"]
        return out, scale

    def _calibrate(self, meth, walls) -> tuple[list[float], int]:
        """(wall times [s] of timing_rounds calls, index of the grid step timed): the grid's
        run nearest CALIBRATION_STEPS steps, its first call (`walls`: one per grid step) and
        timing_rounds - 1 more. One run prices the method: repeating every run would cost
        the rounds over again, an implicit method's runs most of all."""
        cfg = self.cfg
        steps = np.array([round(cfg.horizon / h) for h in cfg.hs])
        j = int(np.argmin(np.abs(steps - CALIBRATION_STEPS)))
        more = [self.integrate(meth, self.x0, self.u, self.p, cfg.hs[j], int(steps[j]))[3]
                for _ in range(cfg.timing_rounds - 1)]
        self.timing["integration_s"] += sum(more)
        return [walls[j], *more], j

    def _trajectories(self, meth) -> pd.DataFrame:
        """Figure runs at the trajectory point: fractions of the predicted limit (of the
        largest grid step for A-stable methods) and one past it, from the initial state."""
        cfg = self.cfg
        t, ref = self.trajectory_reference()
        x0, u, p = self._traj_lanes()
        every = TRAJ_SAMPLES // ALONG_SAMPLES
        with self.clock("metrics_s"):
            jac = frozen.jacobians(self.spec.rhs, t[::every],
                                   np.repeat(ref[None, ::every], len(x0), 0), u, p)
        limit, _, _ = frozen.predicted_limit(meth, frozen.eigenvalues(jac[0]))
        base = limit if math.isfinite(limit) else cfg.hs[-1]
        hs = [max(f * base, cfg.hs[0]) for f in cfg.traj_fractions]
        past = [False] * len(hs)
        if math.isfinite(limit) and limit > 0:
            hs.append(cfg.traj_past_limit * limit)
            past.append(True)
        frames, lanes = [], len(self.x0)
        for start in range(0, len(hs), lanes):
            chunk = hs[start: start + lanes]
            h = np.array(chunk + [chunk[-1]] * (lanes - len(chunk)))
            n = min(self.max_steps, math.ceil(cfg.horizon / h.min() - 1e-9))
            x, _, _, run_s = self.integrate(meth, x0, u, p, h, n)
            self.timing["metrics_s"] += run_s
            for k, hk in enumerate(chunk):
                rows = figure_rows(min(n, math.floor(cfg.horizon / hk + 1e-9)) + 1)
                frames.append(_trajectory_rows(self.spec, meth.name, hk, hk * rows,
                                               x[k, rows], past[start + k]))
        return pd.concat(frames, ignore_index=True)


def _candidates(lo, hi, guess, width, k, first, tau):
    """Up to k candidate log-steps strictly inside the bracket (lo, hi) of log-steps, for a
    bracket wider than tau = log(1 + rel_tol). Where the predicted limit `guess` lies in the
    bracket, the first round probes at it and tau apart around it (the bracket is then
    often done), and later rounds gallop from the bracket's end nearest the guess, `width`
    away (doubling per round), until that passes the bracket's middle; otherwise, and then,
    k evenly spaced points."""
    even = lo + (hi - lo) * np.arange(1, k + 1) / (k + 1)
    if np.isnan(guess) or (hi - lo) <= (k + 1) * tau:
        return even
    if first:
        near = guess + tau * (np.arange(k) - (k - 1) // 2)
        near = near[(near > lo) & (near < hi)]
        return near if len(near) else even
    if 2 * width >= hi - lo:
        return even
    if guess - lo <= hi - guess:
        return lo + width * np.arange(1, k + 1) / k
    return (hi - width * np.arange(1, k + 1) / k)[::-1]


def figure_rows(n: int) -> np.ndarray:
    """Which of a figure run's n states the trajectories table keeps: all up to TRAJ_ROWS,
    else TRAJ_ROWS evenly spread from the first to the last (a figure shows no more, and
    an explicit method on a stiff problem takes millions of steps: 2.5 GB of table for
    vdp1000 over 700 s at 0.2 of rk4's limit)."""
    return np.unique(np.linspace(0, n - 1, min(n, TRAJ_ROWS)).round().astype(int))


def _trajectory_rows(spec, name, h, t, x, past_limit) -> pd.DataFrame:
    df = pd.DataFrame(x, columns=list(spec.states))
    df.insert(0, "t", t)
    df.insert(0, "h", float(h))
    df.insert(0, "method", name)
    df["past_limit"] = past_limit
    return df


def _ratio(meas, pred):
    if math.isinf(meas) and math.isinf(pred):
        return float("nan")                   # both unbounded: no ratio to speak of
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.float64(meas) / pred)


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
    with claim(out, "sweep", overwrite=overwrite):
        return _fill(cfg, Path(out), resume, overwrite, progress, on_chunk, runner)


def _fill(cfg, out: Path, resume, overwrite, progress, on_chunk, runner) -> dict:
    from tqdm import tqdm
    started = time.perf_counter()
    chunks = out / "chunks"
    old = sweep_folder.check_start(cfg, out, resume, overwrite)
    chunks.mkdir(parents=True, exist_ok=True)
    for stale in chunks.glob(".*.tmp*"):           # a chunk cut off while being written
        shutil.rmtree(stale, ignore_errors=True)
    atomic_write(out / "config.toml", _config_copy(cfg))
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
    for name in schema.PARQUET:
        atomic_write(out / f"{name}.parquet", _parquet(tables[name]))
    for name in schema.CSV:
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
    parts = {name: [] for name in schema.CHUNK_TABLES}
    # A table no chunk has a row of keeps its columns (DETEST A5's Jacobian is 0 at t = 0:
    # no chunk lists an eigenvalue), so that readers find the columns they check.
    empty = {}
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
            nonsmooth_points=flagged, nonsmooth_note=nonsmooth.note(lim)))
    return pd.DataFrame(rows, columns=schema.SUMMARY)


def most_common(notes: pd.Series) -> str:
    """The note most operating points share (the first in order on a tie)."""
    return str(notes.value_counts(sort=True).index[0])


def _timing(per_chunk: pd.DataFrame, assemble_s: float, wall_s: float) -> dict:
    # JAX's compiling [s] per method; "reference": the references' and the Jacobians'.
    compile_s = per_chunk.groupby("method")["compile_s"].sum()
    out = {"compile_s": {k: round(float(v), 3) for k, v in compile_s.items() if k != "reference"}}
    out["compile_s"]["reference"] = round(float(per_chunk["ref_compile_s"].sum()
                                                + compile_s.get("reference", 0.0)), 3)
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
                      "bisection_rel_tol": cfg.rel_tol, "narrowing": NARROWING},
        "order_fit": metrics.ORDER_RULE,
        "nonsmooth": nonsmooth.RULE,
        "prediction": frozen.RULE,
        "trajectory_point": dict(zip(cfg.spec.variables, cfg.traj_point)),
        "horizon_s": cfg.horizon, "vehicle": cfg.vehicle, "model": cfg.model,
        "reference": REFERENCE_KINDS[_reference_kind(cfg)].format(_solver(cfg)),
        "error_estimate": ESTIMATES[cfg.error_estimate],
        "newton": cfg.newton_options,
        "model_spec": schema.model_record(cfg.spec),
        "stepzoo_version": ver, "timing_rounds": cfg.timing_rounds,
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
