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

# One line per column's meaning: COLUMN_DOC below. `runs`: one row per (method, h, point).
RUN_STATUS = ["stable", "blowup_t"]
VEHICLE_ERRORS = ["err_pos", "err_final"]          # [m], models with X and Y only
# evals and time_s (time_per_step_s x n_steps, timing.RULE): the two costs of a
# work-precision diagram.
RUN_TAIL = ["evals_per_s", *timing.COLUMNS, "n_steps", "ref_ok", "converged", "err", "evals",
            "time_s"]
# `limits`: one row per (method, point).
LIMIT_TAIL = ["h_pred", "h_meas", "ratio", "order_declared", "order_fit", "h_probe_max",
              "t_bind", "lam_re_bind", "lam_im_bind", "limit_cause"]
# order_h_rho's stiff threshold is metrics.STIFF_H_RHO; summary's order_status compares the
# median observed order with the declared one (metrics.order_status).
ORDER_TAIL = ["order_h_min", "order_h_max", "order_points", "order_note", "rho_max",
              "order_h_rho"]
# summary: one row per method (metrics.own_limits for the solver-limited columns).
SUMMARY = ["method", "family", "order_declared", "order_fit_median", "order_fit_min",
           "order_fit_max", "real_interval", "imag_interval", "h_meas_min", "h_pred_min",
           "worst_ratio", "implicit", "evals_per_step", "points", "solver_failures",
           "order_h_min", "order_h_max", "order_status", "order_h_rho",
           "solver_limited_points", "h_solver_limit_min"]
EIGEN_TAIL = ["lam_re", "lam_im"]
TIMING = ["chunk", "method", "compile_s", "ref_compile_s", "reference_s", "integration_s",
          "stability_s", "metrics_s", "total_s"]

# Non-smooth points by bench.nonsmooth.RULE. Where most points have one and the order falls
# short, summary's order_status says "limited by non-smooth f".
NONSMOOTH_TAIL = ["nonsmooth_t", "nonsmooth_what", "nonsmooth_kind", "nonsmooth_events"]
SUMMARY = [*SUMMARY, "nonsmooth_points", "nonsmooth_note"]

# The stability test's diagnosis just above the measured limit ("modes" rule;
# bench.stability_runs.MODES_RULE), and why measured and predicted differ (metrics.limit_note).
STABILITY_TAIL = ["unstable_state", "unstable_t", "growth_ratio", "ref_growth", "limit_note"]
SUMMARY = [*SUMMARY, "disagreeing_points", "disagreement_note"]

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


# Placeholders for the columns named after each envelope variable and each state.
VARIABLE, STATE = "<variable>", "<state>"
# What each column means, in one line with its unit: the docs' results-tables page is made
# from it, and a test requires a line for every column a table declares.
COLUMN_DOC = {
    "method": "the zoo's method name", "h": "the step size [s]",
    "point": "the operating point's index in the envelope",
    VARIABLE: "the operating point's value of that envelope variable",
    "stable": "no blow-up, and every nonlinear solve converged",
    "blowup_t": "when the run blew up [s] (NaN: it did not)",
    f"err_{STATE}": "largest error of that state over the run [the state's unit]",
    "err_pos": "largest position error over the run [m]",
    "err_final": "position error at the end of the horizon [m]",
    "evals_per_s": "right-hand-side evaluations per simulated second",
    "time_per_step_s": "wall time per step, the fastest of the timed rounds [s]",
    "time_per_step_median_s": "wall time per step, the median round [s]",
    "time_per_step_max_s": "wall time per step, the slowest round [s]",
    "time_per_step_iqr_s": "interquartile range of the rounds' times per step [s]",
    "timing_rounds": "how many timed rounds", "n_steps": "steps of the run",
    "ref_ok": "the reference met its tolerance",
    "converged": "every nonlinear solve of that step's runs converged (explicit: always)",
    "err": "largest error over the run of the error states, each over its scale",
    "evals": "right-hand-side evaluations of the run",
    "time_s": "wall time of the run, as the method's calibration prices it [s]",
    "h_pred": "largest stable step predicted from the frozen-Jacobian eigenvalues along the "
              "reference [s]",
    "h_meas": "largest stable step measured by bisection [s]",
    "ratio": "h_meas / h_pred", "order_declared": "the method's order",
    "order_fit": "observed order on the asymptotic range of steps",
    "h_probe_max": "largest step probed for a blow-up [s]",
    "t_bind": "where along the reference the prediction binds [s]",
    "lam_re_bind": "real part of the binding eigenvalue [1/s]",
    "lam_im_bind": "imaginary part of the binding eigenvalue [1/s]",
    "limit_cause": "what ended the stable range: unstable, solver failed, or none up to "
                   "h_probe_max",
    f"bind_{STATE}": "that state where the prediction binds",
    "order_h_min": "finest step of the order fit [s]",
    "order_h_max": "coarsest step of the order fit [s]",
    "order_points": "steps in the order fit",
    "order_note": "why no asymptotic range was found (asymptotic: one was)",
    "rho_max": "largest spectral radius of the Jacobian along the reference [1/s]",
    "order_h_rho": "order_h_min x rho_max: above the stiff threshold the fit is all stiff",
    "nonsmooth_t": "first time f is not smooth along the reference [s] (NaN: smooth)",
    "nonsmooth_what": "the state or input that jumps there",
    "nonsmooth_kind": "jump (f itself) or kink (its Jacobian)",
    "nonsmooth_events": "how many such points", "model_nan_t": "where the model is not "
    "finite [s]",
    "family": "explicit RK, implicit RK, Rosenbrock, Adams-Bashforth, Adams-Moulton or BDF",
    "order_fit_median": "median observed order over the points",
    "order_fit_min": "smallest observed order", "order_fit_max": "largest observed order",
    "real_interval": "stability interval on the negative real axis (h lambda)",
    "imag_interval": "stability interval on the imaginary axis (h lambda)",
    "h_meas_min": "smallest h_meas over the points that blew up or never failed [s]",
    "h_pred_min": "smallest h_pred over the points [s]",
    "worst_ratio": "the largest h_meas / h_pred", "implicit": "whether it solves equations",
    "evals_per_step": "right-hand-side evaluations per step", "points": "operating points",
    "solver_failures": "runs whose nonlinear solves failed",
    "order_status": "matches, stiff range, below or above declared, no asymptotic range, "
                    "not observable, or limited by non-smooth f",
    "solver_limited_points": "points where a failed solve ended the stable range first",
    "h_solver_limit_min": "their smallest h_meas [s]",
    "nonsmooth_points": "points where f is not smooth",
    "nonsmooth_note": "where, and the remedy",
    "lam_re": "real part of an eigenvalue of df/dx at the initial state [1/s]",
    "lam_im": "imaginary part of that eigenvalue [1/s]", "t": "time [s]",
    "unstable_state": "the state whose deviation was largest where the run just above h_meas "
                      "failed (empty: nothing failed)",
    "unstable_t": "when that run failed [s] (NaN: it did not)",
    "growth_ratio": "that run's perturbation growth over the reference's own, the largest "
                    "over the run and the directions",
    "ref_growth": "the reference's own largest perturbation growth within the stability "
                  "horizon (above `growth`: the model itself diverges)",
    "limit_note": "agrees (ratio within the agreement tolerance), or why h_meas and h_pred "
                  "differ",
    "disagreeing_points": "points whose limit_note is not 'agrees'",
    "disagreement_note": "the most common reason among them (empty: none)",
    STATE: "the state's value", "past_limit": "the sample step past the predicted limit",
}


def run_columns(variables, states, vehicle: bool) -> list[str]:
    return ["method", "h", "point", *variables, *RUN_STATUS,
            *[f"err_{s}" for s in states], *(VEHICLE_ERRORS if vehicle else []), *RUN_TAIL]


def limit_columns(variables, states) -> list[str]:
    return ["method", "point", *variables, *LIMIT_TAIL, *[f"bind_{s}" for s in states],
            *ORDER_TAIL, *NONSMOOTH_TAIL, "model_nan_t", *STABILITY_TAIL]


def eigen_columns(variables) -> list[str]:
    return ["point", *variables, *EIGEN_TAIL]


def model_record(spec) -> dict:
    """The manifest's "model": what a reader needs to name axes and columns."""
    return {"name": spec.name, "states": list(spec.states), "inputs": list(spec.inputs),
            "variables": list(spec.variables), "error_states": list(spec.error_states),
            "error_scales": list(spec.error_scales), "vehicle": spec.vehicle}
