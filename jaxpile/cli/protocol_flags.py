"""A protocol's own options as flags of `pile`, `sweep` and `fit`
(`--polydispersity 0.05` for `--option polydispersity=0.05`), read from the
fields of the protocol's options (`ProtocolSpec.options`)."""

from __future__ import annotations

from jaxpile.cli.parsing import on_off, parse_options
from jaxpile.errors import InputError

DEFAULT_PROTOCOL = {"pile": "lattice", "sweep": "box", "fit": "lattice"}
"""The protocol each command runs when it names none."""


def command_and_protocol(argv: list[str]) -> tuple[str | None, str | None]:
    """The command and the protocol an argument list names (its default when
    it names none), read before the full parse: the protocol's own flags are
    added to the parser for it."""
    command = argv[0] if argv and not argv[0].startswith("-") else None
    protocol = None
    for k, a in enumerate(argv):
        if a == "--protocol" and k + 1 < len(argv):
            protocol = argv[k + 1]
        elif a.startswith("--protocol="):
            protocol = a.split("=", 1)[1]
    return command, protocol or DEFAULT_PROTOCOL.get(command)


def protocol_flags(command: str, protocol: str) -> dict:
    """`{name: spec.Option}`: the options of `protocol` (every stage's, the
    pile's first for a protocol that continues one) that `command` takes as
    flags of their own; for `pile`, less those a generic flag (`--max-steps`,
    `--speed-tol`, ...) sets. Options the command line cannot type (a dict)
    stay `--option`'s."""
    from jaxpile.protocols import PROTOCOLS
    from jaxpile.protocols.spec import declared

    spec = PROTOCOLS.get(protocol)
    if spec is None or command not in DEFAULT_PROTOCOL:
        return {}
    found = {}
    for stage in reversed(spec.chain()):  # a name two stages share is described as the last stage's
        for name, o in declared(stage.options).items():
            found.setdefault(name, o)
    taken = {"n"} | {s.size for s in spec.chain()}  # the size is `--n` (or `--layers`)
    if command == "pile":
        from jaxpile.cli.presentation import presentation

        taken |= set(presentation(protocol).flags.values())
    return {k: o for k, o in found.items() if o.kind is not None and k not in taken}


def add_protocol_flags(parser, command: str, protocol: str) -> None:
    """One `--NAME` flag per option of `protocol` (`protocol_flags`), in a group
    of `--help` of their own, each with its help, unit, range and default.
    A name the command already has a flag for keeps that flag."""
    flags = {k: o for k, o in protocol_flags(command, protocol).items()
             if o.flag not in parser._option_string_actions}
    if not flags:
        return
    group = parser.add_argument_group(f"options of the {protocol} protocol (the same as --option NAME=VALUE)")
    for o in flags.values():
        words = [o.help + (f" ({o.unit})" if o.unit else "")]
        if o.range is not None:
            words.append(f"[{o.range.describe()}]")
        if o.default is not None:
            words.append(f"(default {o.default})")
        kind = {bool: on_off, int: int, float: float, str: str}[o.kind]
        group.add_argument(o.flag, dest=f"protocol_option__{o.name}", type=kind, default=None,
                           metavar={bool: "on|off", int: "N", float: "X", str: "TEXT"}[o.kind],
                           help=" ".join(words).replace("%", "%%"))


def merge_protocol_flags(args) -> None:
    """The protocol's own flags given, appended to `args.option` as
    `NAME=VALUE` (one path from there on); a name given both ways is refused."""
    given = {k.split("__", 1)[1]: v for k, v in vars(args).items()
             if k.startswith("protocol_option__") and v is not None}
    if not given:
        return
    twice = sorted(set(parse_options(args.option)) & set(given))
    if twice:
        raise InputError(f"{', '.join(twice)} given both as a flag and as --option: give it once.")
    text = {True: "on", False: "off"}
    args.option = list(args.option or []) + [
        f"{k}={text[v] if isinstance(v, bool) else v}" for k, v in given.items()]
