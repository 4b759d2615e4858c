"""Each protocol's options as its own code declares them.

An option is a keyword argument of the protocol's `run` or of its set-up
function. Its type and default come from the signature, its help from the
function's docstring (`Args:`), its valid range from the module's
`OPTION_RANGES`. Nothing is kept in a second table: the CLI builds one
`--NAME` flag per option from `declared`, so a new option, or a new
protocol, shows up in `jaxpile pile|sweep|fit --protocol P --help` by being
written.
"""

from __future__ import annotations

import inspect
import re
from typing import Any, Callable, NamedTuple

from jaxpile.ranges import Range

RESERVED = frozenset({"law", "params", "rotation", "dt", "integrator", "dtype", "progress", "n", "layers", "insertions",
                      "pile",
                      "alpha_degrees", "hard_collisions", "pile_params", "box_options", "checkpoint", "resume",
                      "law_options"})
"""Arguments that are not options: the law, the run's machinery, and what the
CLI's own flags set (`--n`, `--slope`, `--dt`, `--hard-collisions`, ...)."""


class Option(NamedTuple):
    """One protocol option.

    Attributes:
      name: the keyword (`release_height`); the CLI flag is `--release-height`.
      kind: `bool`, `int`, `float` or `str`: how the flag's text is read.
      default: the function's default (None: computed by the set-up).
      help: its docstring's words for it ("" when the docstring has none).
      range: its valid range, or None.
    """

    name: str
    kind: type
    default: Any
    help: str
    range: Range | None

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")


def accepted(module) -> frozenset:
    """The keyword arguments `jaxpile pile --option` may set: those of the
    protocol's `run`, plus those of its set-up where `run` forwards `**options`."""
    run = inspect.signature(module.run).parameters
    names = {k for k, v in run.items() if v.kind in (v.KEYWORD_ONLY, v.POSITIONAL_OR_KEYWORD)}
    if any(v.kind is v.VAR_KEYWORD for v in run.values()):
        names |= set(inspect.signature(module.protocol).parameters)
    return frozenset(names - RESERVED)


def docstring_args(function: Callable) -> dict[str, str]:
    """`{name: text}` from a Google-style docstring's `Args:` section. An entry
    naming several arguments (`dt, rotation: ...`) gives each the same text;
    `**options` and the like are skipped."""
    doc = inspect.getdoc(function) or ""
    m = re.search(r"^Args:\n(.*?)(?:\n\S|\Z)", doc, re.S | re.M)
    if m is None:
        return {}
    out, current = {}, []
    for line in m.group(1).splitlines():
        entry = re.match(r"^ {2}(\*{0,2}[\w, ]+?):\s*(.*)$", line)
        if entry and not line.startswith("    "):
            text = [entry.group(2).strip()]
            current = [name.strip() for name in entry.group(1).split(",") if not name.strip().startswith("*")]
            for name in current:
                out[name] = text
        elif current and line.strip():
            text.append(line.strip())
    return {name: " ".join(words) for name, words in out.items()}


def _kind(default, range_: Range | None) -> type:
    if isinstance(default, bool):
        return bool
    if isinstance(default, int):
        return int
    if isinstance(default, float):
        return float
    if isinstance(default, str):
        return str
    return int if range_ is not None and range_.whole else float


def declared(module, names=None) -> dict[str, Option]:
    """`{name: Option}` for the protocol `module`: `names` (default: every
    option `accepted` by its `run`), typed, with help and range, in the order
    of its `run`'s and then its set-up's signature."""
    names = accepted(module) if names is None else frozenset(names)
    functions = [module.run, module.protocol]
    helps: dict[str, str] = {}
    for function in reversed(functions):  # `run`'s words win
        helps.update(docstring_args(function))
    out = {}
    for function in functions:
        for name, parameter in inspect.signature(function).parameters.items():
            if name not in names or name in out:
                continue
            default = None if parameter.default is parameter.empty else parameter.default
            range_ = module.OPTION_RANGES.get(name)
            out[name] = Option(name, _kind(default, range_), default, helps.get(name, ""), range_)
    return out


def option_names(setup, *extra) -> frozenset:
    """The options a sweep of this set-up accepts: its arguments, and `extra` run options."""
    names = set(inspect.signature(setup).parameters) - {"law", "seed", "dt", "dtype"}
    return frozenset(names | set(extra))
