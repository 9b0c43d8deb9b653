"""`stepzoo methods`: the zoo as a table, with each method's stability intervals, whether it
is A- and L-stable, its A(alpha) angle [deg] (90: A-stable; null: not even the negative real
axis is stable) and its damping of infinitely stiff modes |R(-inf)| (null: unbounded)."""
import sys

from stepzoo.output import text_table, to_json


def add_arguments(p):
    p.add_argument("--format", choices=["text", "json"], default="text")


def rows() -> list[dict]:
    from stepzoo.integrators import METHODS, describe
    from stepzoo.integrators.stability import (a_alpha, a_stable, l_stable, stability_intervals,
                                               stiff_decay)
    out = []
    for m in METHODS.values():
        row = describe(m)
        # Rounded to 1e-9: the bisection is exact to round-off (TOL), not to the last bit.
        real, imag = stability_intervals(m)
        row["real_interval"] = None if real == float("inf") else round(real, 9)
        row["imag_interval"] = None if imag == float("inf") else round(imag, 9)
        row["a_stable"], row["l_stable"] = a_stable(m), l_stable(m)
        alpha = a_alpha(m)
        row["a_alpha_deg"] = None if alpha is None else round(alpha, 4)
        decay = stiff_decay(m)
        row["stiff_decay"] = None if decay == float("inf") else round(decay, 9)
        out.append(row)
    return out


def main(args) -> int:
    table = rows()
    if args.format == "json":
        print(to_json(table))
    else:
        cols = ["name", "family", "order", "stages", "steps", "implicit", "rhs_evals_per_step",
                "real_interval", "imag_interval", "a_stable", "l_stable", "a_alpha_deg",
                "stiff_decay"]
        sys.stdout.write(text_table(table, cols) + "\n")
    return 0
