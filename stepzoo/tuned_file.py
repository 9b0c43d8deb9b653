"""The tuned config: the TOML `stepzoo tune` writes (and `tune --for-plans` extends), which
`stepzoo plan` reads as its planner config and `stepzoo export` as the tuning to export.
It is two declared parts in one table: the planner's choice (PlannerChoice) and tune's
evidence for it (TuneEvidence). Only `method` and `h` are required: a planner config written
by hand is the same kind, its choice alone."""
from __future__ import annotations

from typing import Annotated, Literal

from pydantic import ConfigDict, Field

from stepzoo.config_schema import Schema, quantity, ranged

# The shared ranges of validate.RANGES, as field types.
Margin = Annotated[float, ranged("margin")]
PosTol = Annotated[float, ranged("pos_tol")]
Rounds = Annotated[int, ranged("rounds")]
Step = Annotated[float, ranged("step")]
Tol = Annotated[float, ranged("tol")]

Count = Annotated[int, quantity("", "", "a count", ge=0)]
# A measurement tune recorded: NaN where it could not be taken is a record, not a mistake.
Measured = Annotated[float, Field(allow_inf_nan=True)]
Rate = Annotated[float, quantity("", "", "a fraction of the runs", ge=0.0, le=1.0)]
# Planner parameters by name; their types and ranges are the planner's (the planner kind).
PlannerValues = dict[str, float | int | bool | str]


class Calibrated(Schema):
    """[calibration.methods.NAME]: one method's measured cost per step."""
    h: Step = Field(description="the step it was timed at [s]")
    n_steps: Count = Field(description="steps of one timed call")
    per_step_s: Measured = Field(description="wall time per step, per trajectory [s]")
    spread_s: Measured = Field(description="the spread of per_step_s over the rounds [s]")


class Calibration(Schema):
    """[calibration]: how tune timed the qualifying methods, in the planner's call."""
    batch: Count = Field(description="trajectories per timed call")
    interval_s: float = Field(description="simulated time of one call [s]")
    rounds: Rounds = Field(description="timed rounds, the fastest kept")
    tie_max: float = Field(description="largest relative time difference that is a tie")
    xla_flags: str = Field("", description="XLA_FLAGS while timing")
    methods: dict[str, Calibrated] = Field({}, description="each qualifying method's timing")


class RunnerUp(Schema):
    """[[runners_up]]: a method tune did not choose, and why; one that qualifies has its
    cheapest qualifying step."""
    method: str = Field(description="the method's zoo name")
    h: Step | None = Field(None, description="its cheapest qualifying step [s] (absent: none "
                           "qualifies)")
    qualifies: bool = Field(True, description="some step meets the tolerance and the margin")
    cost_evals_per_s: Measured | None = Field(None, description="RHS evaluations per simulated "
                                           "second")
    cost_time_per_s: Measured | None = Field(None, description="wall time per simulated second "
                                          "[s]")
    cost_time_spread_per_s: Measured | None = Field(None, description="its spread [s]")
    reason: str = Field("", description="why it is not the choice")


class Candidate(Schema):
    """[[plans.candidates]]: one candidate's evidence from planning the queries."""
    integrator: str = Field(description='"method:h" label')
    method: str = Field(description="the method's zoo name")
    h: Step = Field(description="its step [s]")
    runs: Count = Field(description="plans made")
    exact: Count = Field(description="plans that reached the goal exactly")
    exact_rate: Rate = Field(description="exact / runs")
    median_time_s: Measured | None = Field(None, description="median plan time [s]")
    median_replay_deviation_m: Measured | None = Field(None, description="median over exact "
                                                    "plans of the replay's deviation [m]")
    max_replay_deviation_m: Measured | None = Field(None, description="largest replay deviation "
                                                 "[m]")
    replay_collisions: Count = Field(0, description="replayed exact plans that collide")
    within_tol: bool = Field(description="every replay within the tolerance")
    verdict: str = Field(description="why it was chosen or not")


class Plans(Schema):
    """[plans]: the evidence of `tune --for-plans`: the qualifying candidates planned."""
    queries: str = Field(description="the query set planned")
    queries_sha256: str = Field(description="its sha256")
    queries_count: Count = Field(description="queries in it")
    runs: Count = Field(description="runs per query")
    seed: Count = Field(description="the first run's seed")
    seeds: tuple[Count, ...] = Field(description="every run's seed")
    speed_mps: float = Field(description="the tree's speed [m/s]")
    replay_tol_m: PosTol = Field(description="the replay's tolerance [m]")
    replay_tol_from: str = Field(description="where the tolerance came from")
    chosen: str = Field(description='the chosen "method:h"')
    tune_choice: str = Field(description='tune\'s own choice, "method:h"')
    why: str = Field(description="why the chosen one")
    tune_why: str = Field(description="why tune chose its own")
    planner: PlannerValues = Field(description="every planner parameter the plans used")
    candidates: tuple[Candidate, ...] = Field(description="each candidate's evidence, best "
                                              "first")


class StiffMode(Schema):
    """[stiffness.mode]: the mode that bounds explicit steps, where it binds."""
    method: str = Field(description="the explicit method with the largest limit")
    lambda_re_per_s: float = Field(description="its eigenvalue's real part [1/s]")
    lambda_im_per_s: float = Field(description="|its imaginary part| [1/s]")
    t_s: float = Field(description="where along the reference it binds [s]")
    point: dict[str, float] = Field(description="the operating point, by envelope variable")
    state: str | None = Field(None, description="the state with the largest participation "
                              "factor in it")
    participation: float | None = Field(None, description="that state's participation "
                                        "factor (0..1)")


class Stiffness(Schema):
    """[stiffness]: whether the model is stiff at the tolerance (bench/model/stiffness.py), at
    the operating point where accuracy allows the most over the explicit limit."""
    stiff: bool = Field(description="accuracy allows stiff_ratio x the largest explicit limit "
                        "at some point")
    h_explicit_max_s: Measured | None = Field(None, description="the largest step an "
                                           "explicit method may take at that point [s]")
    h_accurate_max_s: Measured | None = Field(None, description="the largest step some method "
                                           "meets the tolerance at there, within its limits "
                                           "[s]")
    accurate_method: str | None = Field(None, description="that method")
    ratio: Measured | None = Field(None, description="h_accurate_max_s / h_explicit_max_s")
    stiff_ratio: float = Field(description="the ratio from which a model is stiff")
    mode: StiffMode | None = Field(None, description="the binding mode")
    says: str = Field("", description="the finding in words")
    stiff_points: Count | None = Field(None, description="the operating points where the "
                                       "model is stiff")
    points: Count | None = Field(None, description="the operating points assessed")


class TunedEnvelope(Schema):
    """[envelope]: the swept envelope the choice holds over: each variable = [least,
    largest], and `points`."""
    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[str, tuple[float, float]] = Field(init=False)
    points: Count = Field(description="operating points the choice was checked at")


class PlannerChoice(Schema):
    """What the planner reads of a tuned config: the integration method and step it uses,
    planner parameters over their defaults, and where the choice came from. A planner config
    written by hand is this part alone."""
    method: str = Field(description="the integration method, a zoo name")
    h: Step = Field(description="the integration step [s]")
    planner: PlannerValues = Field({}, description="planner parameters over their defaults, "
                                   "by name (the planner kind)")
    provenance: str | None = Field(None, description="where the choice came from")
    why: str = Field("", description="why this (method, h)")


class TuneEvidence(Schema):
    """What tune's choice came from: the tolerance and margin tuned to, the choice's costs,
    errors and stable limits, the model's stiffness, the sweep and its envelope, how the
    costs were timed, the runners-up, and the plans of `tune --for-plans`."""
    pos_tol_m: PosTol | None = Field(None, description="the position tolerance tuned to [m]")
    tol: Tol | None = Field(None, description="the error tolerance tuned to, in the sweep's "
                            "error norm")
    margin: Margin | None = Field(None, description="the stability margin tuned with")
    cost: Literal["time", "evals"] | None = Field(None, description="what ranked the "
                                                  "candidates")
    cost_evals_per_s: Measured | None = Field(None, description="RHS evaluations per simulated "
                                           "second of the choice")
    cost_time_per_s: Measured | None = Field(None, description="wall time per simulated second "
                                          "of the choice [s]")
    cost_time_spread_per_s: Measured | None = Field(None, description="its spread [s]")
    err_pos_max_m: Measured | None = Field(None, description="the choice's worst position error "
                                        "[m]")
    err_max: Measured | None = Field(None, description="the choice's worst error, in the sweep's "
                                  "norm")
    h_meas_min_s: Measured | None = Field(None, description="the smallest measured largest "
                                       "stable step of the choice's method [s]")
    h_pred_min_s: Measured | None = Field(None, description="the smallest predicted largest "
                                       "stable step of the choice's method [s]")
    h_over_h_pred_max: Measured | None = Field(None, description="the choice's largest h / "
                                            "h_pred over the points (above 1 only with "
                                            "allow_beyond_predicted_limit)")
    allow_beyond_predicted_limit: bool = Field(False, description="tuned with "
                                               "--allow-beyond-predicted-limit: the predicted "
                                               "limit was not kept")
    stiff: bool | None = Field(None, description="whether the model is stiff at the tolerance")
    stiffness: Stiffness | None = Field(None, description="why (bench/model/stiffness.py)")
    horizon_s: Measured | None = Field(None, description="the sweep's "
                                    "horizon [s] (NaN: not recorded)")
    model: str | None = Field(None, description="the swept model")
    sweep_config_sha256: str | None = Field(None, description="the sweep config's sha256")
    sweep: str | None = Field(None, description="the sweep folder")
    sweep_created: str | None = Field(None, description="when the sweep was created (its "
                                      "manifest's `created`)")
    envelope: TunedEnvelope | None = Field(None, description="the swept envelope")
    calibration: Calibration | None = Field(None, description="how the costs were timed")
    runners_up: tuple[RunnerUp, ...] = Field((), description="the other methods, ranked")
    plans: Plans | None = Field(None, description="the evidence of tune --for-plans")


class TunedFile(TuneEvidence, PlannerChoice):
    """A tuned (planner) config: the integration method and step the planner uses, tune's
    reasons and evidence, and planner parameters over their defaults."""

    @property
    def choice(self) -> PlannerChoice:
        """The planner's part."""
        return PlannerChoice.model_construct(**{k: getattr(self, k)
                                                for k in PlannerChoice.model_fields})

    @property
    def evidence(self) -> TuneEvidence:
        """Tune's evidence."""
        return TuneEvidence.model_construct(**{k: getattr(self, k)
                                               for k in TuneEvidence.model_fields})
