"""The sweep's tables, declared once: each table's columns (fixed ones, and those named after
the model's envelope variables and states), sort keys and files. The sweep writes by it,
tune and the report read by it; a column named here is a contract."""
from __future__ import annotations

from stepzoo.bench import timing

# Tables of a chunk, and the files of the finished results folder.
CHUNK_TABLES = ("runs", "limits", "eigenvalues", "trajectories", "timing")
PARQUET = ("runs", "limits", "eigenvalues", "trajectories", "summary")
CSV = ("limits", "summary")
SORT = {"runs": ["method", "h", "point"], "limits": ["method", "point"],
        "eigenvalues": ["point", "lam_re", "lam_im"], "trajectories": ["method", "h", "t"],
        "timing": ["chunk"]}

# `runs`: one row per (method, h, point). `stable`: no blow-up and every nonlinear solve
# converged; `converged`: every solve of that step's runs converged (explicit: always);
# `err` [scaled]: largest error over the run of the error states, each over its scale.
RUN_STATUS = ["stable", "blowup_t"]
VEHICLE_ERRORS = ["err_pos", "err_final"]          # [m], models with X and Y only
# evals: right-hand-side evaluations of the run; time_s [s]: its wall time, the fastest of
# the timed rounds as the method's calibration prices it (time_per_step_s x n_steps; see
# timing.RULE): the two costs of a work-precision diagram.
RUN_TAIL = ["evals_per_s", *timing.COLUMNS, "n_steps", "ref_ok", "converged", "err", "evals",
            "time_s"]
# `limits`: one row per (method, point). h_pred [s] from the frozen-Jacobian eigenvalues
# along the reference, binding at t_bind [s] on eigenvalue lam_bind; h_meas [s] by
# bisection; limit_cause: what ended the stable range ("unstable", "solver failed", or
# "none" when nothing failed up to h_probe_max).
LIMIT_TAIL = ["h_pred", "h_meas", "ratio", "order_declared", "order_fit", "h_probe_max",
              "t_bind", "lam_re_bind", "lam_im_bind", "limit_cause"]
# order_fit: the observed order on the range of steps [s] order_h_min..order_h_max
# (order_points steps), order_note why no asymptotic range was found ("asymptotic" if one
# was); rho_max [1/s]: the largest spectral radius of the Jacobian along the reference, and
# order_h_rho = order_h_min * rho_max: above metrics.STIFF_H_RHO the whole fit lies in the
# stiff range. summary's order_status compares the median observed order with the declared
# one (median order_h_rho: see metrics.order_status).
ORDER_TAIL = ["order_h_min", "order_h_max", "order_points", "order_note", "rho_max",
              "order_h_rho"]
# summary: h_meas_min and worst_ratio are over the points where the method blew up or nothing
# failed; solver_limited_points counts those where a failed nonlinear solve ended the stable
# range first, h_solver_limit_min [s] their smallest h_meas (metrics.own_limits).
SUMMARY = ["method", "family", "order_declared", "order_fit_median", "order_fit_min",
           "order_fit_max", "real_interval", "imag_interval", "h_meas_min", "h_pred_min",
           "worst_ratio", "implicit", "evals_per_step", "points", "solver_failures",
           "order_h_min", "order_h_max", "order_status", "order_h_rho",
           "solver_limited_points", "h_solver_limit_min"]
EIGEN_TAIL = ["lam_re", "lam_im"]
TIMING = ["chunk", "method", "compile_s", "ref_compile_s", "reference_s", "integration_s",
          "stability_s", "metrics_s", "total_s"]

# nonsmooth_t [s]: the first time where f is not smooth along the point's reference (NaN
# where it is smooth), nonsmooth_what the state or input that jumps, nonsmooth_kind "jump"
# (f itself) or "kink" (its Jacobian), nonsmooth_events how many such points (rule:
# bench.nonsmooth.RULE). Where most points have one and the order falls short, summary's
# order_status says "limited by non-smooth f"; its nonsmooth_points counts them and
# nonsmooth_note says where and the remedy.
NONSMOOTH_TAIL = ["nonsmooth_t", "nonsmooth_what", "nonsmooth_kind", "nonsmooth_events"]
SUMMARY = [*SUMMARY, "nonsmooth_points", "nonsmooth_note"]

# Measured wall times: they differ between two runs of the same config.
MEASURED = {*timing.MEASURED, "time_s", "compile_s", "ref_compile_s", "reference_s",
            "integration_s", "stability_s", "metrics_s", "total_s"}

# What a reader needs of a results folder, whatever the model: the report and tune check
# these and read the rest (envelope variables, states) from the manifest's "model".
REQUIRED = {
    "runs": ["method", "h", "point", "stable", "evals_per_s", "time_per_step_s"],
    "limits": ["method", "point", "h_pred", "h_meas"],
    "summary": ["method", "family", "order_declared", "order_fit_median", "real_interval",
                "imag_interval", "h_meas_min", "h_pred_min", "worst_ratio"],
    "eigenvalues": ["point", "lam_re", "lam_im"],
    "trajectories": ["method", "h", "t"],
}


def run_columns(variables, states, vehicle: bool) -> list[str]:
    return ["method", "h", "point", *variables, *RUN_STATUS,
            *[f"err_{s}" for s in states], *(VEHICLE_ERRORS if vehicle else []), *RUN_TAIL]


def limit_columns(variables, states) -> list[str]:
    return ["method", "point", *variables, *LIMIT_TAIL, *[f"bind_{s}" for s in states],
            *ORDER_TAIL, *NONSMOOTH_TAIL, "model_nan_t"]   # [s] where the model is not finite


def eigen_columns(variables) -> list[str]:
    return ["point", *variables, *EIGEN_TAIL]


def model_record(spec) -> dict:
    """The manifest's "model": what a reader needs to name axes and columns."""
    return {"name": spec.name, "states": list(spec.states), "inputs": list(spec.inputs),
            "variables": list(spec.variables), "error_states": list(spec.error_states),
            "error_scales": list(spec.error_scales), "vehicle": spec.vehicle}
