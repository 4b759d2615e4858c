"""The valid range of every number a user gives jaxpile, and the one check that
enforces it.

Each law declares `RANGES` (its parameters), each protocol a range on each field
of its options (`protocols.spec.option`) and the command line `cli.FLAG_RANGES`
(its numeric flags). One `Range` states the interval, whether it holds whole numbers only,
and why a bound is where it is; `check` answers a value outside it with one
line in one format, `"<name> must be <range>; got <value>."`, and the same
table writes the docstrings, the `--help` text, the inputs table of docs/cli.md and
the catalogue test's expectations. The property tests (tests/test_input_properties.py)
draw values across and beyond each range.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import numpy as np

from jaxpile.errors import InputError


@dataclasses.dataclass(frozen=True)
class Range:
    """An interval of valid values.

    Attributes:
      low, high: the bounds (None: unbounded on that side; every value must be finite).
      low_open, high_open: the bound itself is excluded.
      whole: only whole numbers.
      why: a few words on the bound (printed after the range).
      unit: what a whole number counts (`disks`, `steps`), for the message.
    """

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    whole: bool = False
    why: str = ""
    unit: str = ""

    def describe(self) -> str:
        """E.g. `> 0`, `>= 0 and <= 1000`, `a positive whole number of disks`."""
        of = f" of {self.unit}" if self.unit else ""
        if self.whole and self.low == 1 and not self.low_open and self.high is None:
            return f"a positive whole number{of}"
        parts = []
        if self.low is not None:
            parts.append(f"{'>' if self.low_open else '>='} {_number(self.low)}")
        if self.high is not None:
            parts.append(f"{'<' if self.high_open else '<='} {_number(self.high)}")
        text = " and ".join(parts) or "finite"
        return f"{text}, a whole number{of}" if self.whole else text

    def contains(self, value: float) -> bool:
        if not math.isfinite(value):
            return False
        if self.whole and value != math.floor(value):
            return False
        if self.low is not None and (value < self.low or (self.low_open and value == self.low)):
            return False
        if self.high is not None and (value > self.high or (self.high_open and value == self.high)):
            return False
        return True

    def check(self, name: str, value, scalar: bool = False):
        """`value` as a Python number (an int when `whole`), or `InputError`
        naming `name`, the range and the value. Arrays (batched parameters) are
        checked element by element and returned as they are, unless `scalar`."""
        if not is_number_like(value):
            raise InputError(f"{name} must be {self._a_number()}; got {value!r}.")
        if isinstance(value, numbers.Real):
            return self._check_scalar(name, value)
        if _is_tracer(value):
            return value  # inside a trace (a fit, a vmapped sweep): checked where it was made
        array = np.asarray(value)
        if array.size == 0:
            raise InputError(f"{name} must be {self._a_number()}; got {value!r}.")
        if array.ndim == 0:
            self._check_scalar(name, array.item())
            return value
        if scalar:
            raise InputError(f"{name} must be one number {self.describe()}; got {value!r}.")
        for v in array.reshape(-1).tolist():
            self._check_scalar(name, v)
        return value

    def _a_number(self) -> str:
        """"a number >= 0", or the description itself where it already says what
        the number is ("a positive whole number of disks")."""
        text = self.describe()
        return "a finite number" if text == "finite" else text if text.startswith("a ") else f"a number {text}"

    def _check_scalar(self, name, value):
        v = float(value) if not isinstance(value, numbers.Integral) else int(value)
        if isinstance(v, float) and not math.isfinite(v):
            rest = "" if self.describe() == "finite" else " and " + self.describe()
            raise InputError(f"{name} must be finite{rest}; got {value!r}.")
        if isinstance(v, int) and abs(v) > 1e300:  # beyond float range: no bound here is that far out
            raise InputError(f"{name} must be {self.describe()}; got an integer of {len(str(abs(v)))} digits.")
        if not self.contains(float(v)):
            why = f" ({self.why})" if self.why else ""
            raise InputError(f"{name} must be {self.describe()}{why}; got {value!r}.")
        return int(v) if self.whole else v


def _number(x: float) -> str:
    """1000 -> `1000`, 1e9 -> `1e9`, 2**31 - 1 -> `2,147,483,647`, 1e-12 -> `1e-12`."""
    if float(x).is_integer() and abs(x) < 1e5:
        return str(int(x))
    exponent = math.log10(abs(x))
    if exponent.is_integer():
        return f"{'-' if x < 0 else ''}1e{int(exponent)}"
    if float(x).is_integer():
        return f"{int(x):,}"
    return f"{x:g}"


def is_number_like(value) -> bool:
    """A number, a numeric array or a JAX tracer; not None, a bool, text or a
    ragged list (the one test `Range.check` and the laws' `make_params` share)."""
    if value is None or isinstance(value, (str, bytes, bool, np.bool_)):
        return False
    if isinstance(value, numbers.Real) or _is_tracer(value):
        return True
    try:
        return np.asarray(value).dtype.kind in "iuf"
    except Exception:  # a ragged list, an object numpy cannot read
        return False


def _is_tracer(value) -> bool:
    try:
        import jax

        return isinstance(value, jax.core.Tracer)
    except Exception:
        return False


POSITIVE = Range(low=0, low_open=True)
NON_NEGATIVE = Range(low=0)
COUNT = Range(low=1, whole=True)
DISKS = Range(low=1, whole=True, unit="disks")
"""A disk count (the memory check, `jaxpile.budget`, bounds it above)."""
SPHERES = Range(low=1, whole=True, unit="spheres")
"""A sphere count (as `DISKS`)."""
STEPS = Range(low=1, high=2**31 - 1, whole=True, unit="steps", why="the step counter is 32-bit")
SEED = Range(low=0, high=2**32 - 1, whole=True, why="numpy's random generators take 32-bit seeds")
FRACTION = Range(low=0, high=1)
FINITE = Range(low=-1e9, high=1e9)
SIZE = Range(low=1e-9, high=1e9, why="in the protocol's units; beyond, host arithmetic over- or underflows")
"""A length, mass, time or speed of a protocol's set-up."""
SPEED = Range(low=0, low_open=True, high=1e9)
"""A speed threshold (at rest below it): any positive value, however small."""
SPAN = Range(low=0, high=1e9)
"""A length or time that may be zero (a spread, a hold time, a gap)."""
TIME_STEP = Range(low=1e-12, high=1e6, why="in the protocol's time units; the run checks its stability limit")
ANGLE = Range(low=0, high=90, low_open=True, high_open=True, unit="")


def check(name: str, value, range_: Range):
    """`range_.check(name, value)`: the one check every layer calls."""
    return range_.check(name, value)


def check_all(ranges: dict, values: dict) -> dict:
    """Checks each `values[name]` that has a range, one number each; returns the
    values with the checked numbers. None passes: it stands for "the default"."""
    out = dict(values)
    for name, value in values.items():
        if name in ranges and value is not None:
            out[name] = ranges[name].check(name, value, scalar=True)
    return out


def table(ranges: dict) -> str:
    """`name: range` lines, for docstrings and `--help`."""
    return "\n".join(f"  {name}: {r.describe()}{f' ({r.why})' if r.why else ''}" for name, r in ranges.items())


def doc_section(ranges: dict, title: str) -> str:
    """A docstring section listing `ranges` under `title`, indented as the
    Google-style sections around it."""
    body = "\n".join(f"      {line.strip()}" for line in table(ranges).splitlines())
    return f"\n\n    {title}:\n{body}\n"


def inline(ranges: dict) -> str:
    """`name range, name range`: one line, for `--help`."""
    return "; ".join(f"{name} {r.describe()}" for name, r in ranges.items())


MAX_STEPS = 2**31 - 1
"""The step counter (`SimState.step`) and the protocols' step rules are 32-bit."""


def steps_of(name: str, time_value: float, dt: float, rounding=round) -> int:
    """`time_value / dt` as a whole number of steps (at least 1), refused when
    the 32-bit step counter cannot hold it (a tiny dt against a long time)."""
    count = time_value / dt
    if not math.isfinite(count) or count > MAX_STEPS:
        raise InputError(f"{name} = {time_value:g} is {count:.3g} steps of dt = {dt:g}, beyond the 32-bit step "
                         f"counter ({MAX_STEPS:,}): use a larger dt or a smaller {name}.")
    return max(1, int(rounding(count)))
