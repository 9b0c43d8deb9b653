"""A number's range as plain data: what it is, its unit, its bounds and why they are where they
are. validate.RANGES holds the shared ones; config_schema turns a Range into a pydantic type
for a config file's field, and words a range the same way in every message."""
import math
from dataclasses import dataclass

BOUNDS = ("ge", "gt", "le", "lt")


@dataclass(frozen=True)
class Range:
    what: str                 # names it in messages ("a step size"; "": the number alone)
    unit: str                 # of the bounds ("" for none)
    reason: str               # why the bounds are where they are
    whole: bool = False       # a whole number
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None

    def bounds(self) -> dict:
        """The bounds given, as pydantic's keywords."""
        return {k: getattr(self, k) for k in BOUNDS if getattr(self, k) is not None}

    def words(self) -> str:
        """"a step size: a number in [1e-09, 100] s (why)"."""
        show = (lambda v: f"{int(v)}") if self.whole else (lambda v: f"{v:g}")
        lo = next(((k, v) for k, v in self.bounds().items() if k in ("ge", "gt")), None)
        hi = next(((k, v) for k, v in self.bounds().items() if k in ("le", "lt")), None)
        kind = "whole number" if self.whole else "number"
        if lo and hi:
            span = (f"in {'[' if lo[0] == 'ge' else '('}{show(lo[1])}, {show(hi[1])}"
                    f"{']' if hi[0] == 'le' else ')'}")
        else:
            ops = {"ge": ">=", "gt": ">", "le": "<=", "lt": "<"}
            span = " and ".join(f"{ops[k]} {show(v)}" for k, v in filter(None, (lo, hi)))
        unit = f" {self.unit}" if self.unit else ""
        what = f"{self.what}: " if self.what else ""
        return f"{what}a {kind} {span}{unit} ({self.reason})"

    def valid(self, value):
        """`value` as a float (an int when whole) if it is a finite number in range, else None.
        A flag's whole number may come as a float (5.0); a bool is no number."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return None
        if not math.isfinite(value):
            return None
        if self.whole:
            if not float(value).is_integer():
                return None
            value = int(value)
        else:
            value = float(value)
        inside = ((self.ge is None or value >= self.ge) and (self.gt is None or value > self.gt)
                  and (self.le is None or value <= self.le)
                  and (self.lt is None or value < self.lt))
        return value if inside else None
