"""A protocol declared once: its options and its `ProtocolSpec`.

A protocol module holds its physics (set-up, driver, measurements) and one
`SPEC = ProtocolSpec(...)`. Its options are a frozen dataclass derived from
`Options` whose fields are made by `option(default, range=..., help=...)`: each
field states its default, valid range, unit and help, and the options are
checked when they are made. From that one declaration come the protocol's run
(`jaxpile.protocols.running.run`), its batch in a sweep and an ensemble fit,
its command-line flags and `--help`, and the inputs table of the docs: nothing
reads a signature or a docstring. How the commands show it and what a batch
reads of it are declared above this layer, by the protocol's name
(`jaxpile.cli.presentation`, `jaxpile.batches`).

Every function in a spec has one fixed signature, listed on `ProtocolSpec`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from jaxpile import ranges
from jaxpile.errors import InputError
from jaxpile.protocols import stages
from jaxpile.protocols.base import REGISTERED, Setting
from jaxpile.protocols.running import run as run_protocol
from jaxpile.ranges import Range


def option(default: Any = None, *, help: str, range: Range | None = None, unit: str = ""):
    """A field of a protocol's options: its default, help, valid range and unit.

    An option whose default is None and that has no range (a dict, an object)
    is set from Python or by `--option NAME=VALUE`, not by a flag of its own.
    """
    return field(default=default, metadata={"help": help, "range": range, "unit": unit})


@dataclass(frozen=True)
class Options:
    """The base of every protocol's options: each field's range is checked when
    the options are made (None passes where it is the field's default: "the
    set-up's default"), then the rules between fields (`validate`)."""

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value, range_ = getattr(self, f.name), f.metadata.get("range")
            if range_ is not None and (value is not None or f.default is not None):  # None: "the default"
                object.__setattr__(self, f.name, range_.check(f.name, value, scalar=True))
        self.validate()

    def validate(self) -> None:
        """Raises `InputError` when options that are each in range do not work
        together (a rest speed above the speed that means motion)."""

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def of(cls, values: dict, what: str):
        """The options with `values` (a dict) over the defaults; an unknown name is refused."""
        unknown = set(values) - set(cls.names())
        if unknown:
            raise InputError(f"unknown option(s) {sorted(unknown)} for {what}; known: {', '.join(cls.names())}.")
        return cls(**values)

    def replace(self, **changes):
        """These options with `changes` (checked as new ones are)."""
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


class Option(NamedTuple):
    """One option as the command line and the docs show it.

    Attributes:
      name: the field name (`release_height`); the flag is `--release-height`.
      kind: `bool`, `int`, `float` or `str`: how a flag's text is read; None
        for an option only Python or `--option` can give (a dict).
      default: the field's default (None: computed by the set-up).
      help: the field's help.
      range: its valid range, or None.
      unit: its unit ("" where it has none or the range says it).
    """

    name: str
    kind: type | None
    default: Any
    help: str
    range: Range | None
    unit: str

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")


def _kind(default, range_: Range | None) -> type | None:
    for kind in (bool, int, float, str):  # bool first: a bool is an int
        if isinstance(default, kind):
            return kind
    if range_ is None:
        return None
    return int if range_.whole else float


def declared(options: type) -> dict[str, Option]:
    """`{name: Option}` of an options dataclass, in field order."""
    return {f.name: Option(f.name, _kind(f.default, f.metadata.get("range")), f.default, f.metadata.get("help", ""),
                           f.metadata.get("range"), f.metadata.get("unit", ""))
            for f in dataclasses.fields(options)}


def ranges_of(options: type) -> dict[str, Range]:
    """`{name: Range}` of the options that have one."""
    return {name: o.range for name, o in declared(options).items() if o.range is not None}



@dataclass(frozen=True)
class ProtocolSpec:
    """A protocol: what one pile's run, a batch and the commands need, declared once.

    The functions, each with one signature:

    - `setup(options, *, law, seed, dt, dtype) -> Setup`; a protocol that
      `starts_from` another takes that one's end state first:
      `setup(pile, options, *, law, dt) -> Setup`.
    - `simulator(options, *, law, dt, rotation, integrator, chunk_steps,
      law_options) -> Simulator` (None for `rotation`, `integrator`,
      `chunk_steps`: the protocol's own; `law_options`: the law's readings
      beyond rotation, such as `{"rolling": "sds"}`).
    - `phases(setup, options) -> tuple[stages.Phase, ...]`: the run, as
      phases of at most so many steps, each ended early where its traceable
      `until` holds at a chunk's end (the pour: every disk poured, then a run
      to rest). One pile and a batch run them alike (`stages.run_phases`);
      they count from the set-up's `info["start_step"]` for a continued protocol.
    - `measure(sim, params, state, setup, options) -> dict`: what a run reports.
      One pile's whole output is the same for every protocol
      (`running.record`: the measurements, the run's steps, phases, rest and
      timings, the set-up's info); `setup` refuses options that cannot work
      with the pile it builds.
    - `pile_facts(pile, setup) -> dict`, optional with `starts_from`: what the
      pile was when this protocol took it over (the tilt: its angle of repose).

    Attributes:
      name: the protocol's registered name.
      options: its options dataclass (an `Options`).
      setting: its paper's law, each law's parameters, dt and rotation
        (`base.Setting`: `law_and_params`, `default_dt` and `default_law` read it).
      size: the option a sweep's and the command line's `--n` (or `--layers`) sets.
      continues: the name of the protocol whose end state this one continues,
        contact history kept (the tilt continues a box pile); a batch runs the
        two as stages. By name, so that no protocol module imports another;
        `starts_from` is that protocol's spec.

    What the commands show of a protocol is `jaxpile.cli.presentation`'s, what
    a batch reads `jaxpile.batches`', its pathwise fit `jaxpile.fit.problem`'s,
    each keyed by the protocol's name.
    """

    name: str
    options: type
    setting: Setting
    setup: Callable
    simulator: Callable
    phases: Callable
    measure: Callable
    size: str = "n"
    continues: str | None = None
    pile_facts: Callable | None = None

    def __post_init__(self):
        if not (isinstance(self.options, type) and issubclass(self.options, Options)):
            raise TypeError(f"{self.name}: options must be an Options dataclass; got {self.options!r}.")

    @property
    def starts_from(self) -> ProtocolSpec | None:
        """The registered spec whose end state this one continues (`continues`), or None."""
        if self.continues is None:
            return None
        if self.continues not in REGISTERED:
            raise InputError(f"the {self.name} protocol continues {self.continues!r}, which is not registered.")
        return REGISTERED[self.continues]

    def budget(self, p, options) -> int:
        """The most steps the set-up `p` runs: its phases' in all."""
        return stages.budget(self.phases(p, options))

    @property
    def default_law(self) -> str:
        """The law of its paper (`setting.law`)."""
        return self.setting.law

    def default_dt(self, law) -> float:
        """The time step `law` runs this protocol with (`setting.dt_of`)."""
        return self.setting.dt_of(law)

    def law_and_params(self, law, params=None, rotation=None, dtype=None, law_options: dict | None = None):
        """`(law module, ContactLaw, params)` of a run (`Setting.law_and_params`)."""
        return self.setting.law_and_params(law, params, rotation, dtype, law_options)

    def make_options(self, values: dict | None = None, **more):
        """This protocol's options from a dict and keywords (a sweep's `n` names
        the size, whatever the option is called); unknown names refused."""
        values = {**(values or {}), **more}
        if self.size != "n" and "n" in values and "n" not in self.options.names():
            if values.get(self.size) is not None:
                raise InputError(f"give the {self.name} pile's size once: n or {self.size}, not both.")
            values[self.size] = values.pop("n")
        return self.options.of(values, f"the {self.name} protocol")

    def chain(self) -> tuple[ProtocolSpec, ...]:
        """The specs a run goes through in order: the pile's first, this one last."""
        return (*(() if self.starts_from is None else self.starts_from.chain()), self)

    def set_up(self, law: str | None = None, size=None, *, seed: int = 0, dt: float | None = None, dtype=None,
               pile=None, **options):
        """This protocol's `Setup` from keywords, e.g. `box.SPEC.set_up("hooke", 72, width=1.6)`;
        a continued protocol's takes the `pile` it continues."""
        law = law or self.default_law
        if size is not None:
            options[self.size] = size
        o = self.make_options(options)
        dt = self.default_dt(law) if dt is None else ranges.TIME_STEP.check("dt", dt, scalar=True)
        if self.starts_from is not None:
            if pile is None:
                raise InputError(f"the {self.name} protocol continues a pile: give the pile (a state) it starts from.")
            return self.setup(pile, o, law=law, dt=dt)
        return self.setup(o, law=law, seed=ranges.SEED.check("seed", seed, scalar=True), dt=dt, dtype=dtype)

    def run(self, law: str | None = None, size=None, **kwargs):
        """One pile from set-up to measurements: `jaxpile.protocols.running.run(self, ...)`."""
        return run_protocol(self, law, size, **kwargs)

    def measure_members(self, sim, params, state, setups, **options) -> list[dict]:
        """Each member's measurements of a batch run by hand (an `Ensemble`
        of this protocol's `set_up`s): `measure` on member k with its params
        and set-up, `options` as the set-ups were made with (the size as `n`).

            ens = jaxpile.ensemble.Ensemble(sim)
            state = ens.run(params, ens.init(params, piles), steps, until=...)
            angles = [m["repose_cumulative_parabola"] for m in box.SPEC.measure_members(sim, params, state, piles)]
        """
        from jaxpile.engine.batch import member

        o = self.make_options(options)
        if isinstance(params, (list, tuple)):
            if len(params) != len(setups):
                raise InputError(f"got {len(params)} params for {len(setups)} set-ups; give one per member.")
            per_member = list(params)
        else:
            per_member = [params] * len(setups)
        return [self.measure(sim, per_member[k], member(state, k), setups[k], o) for k in range(len(setups))]


__all__ = ["Option", "Options", "ProtocolSpec", "declared", "option", "ranges_of"]
