"""A protocol's own options as flags of `pile`, `sweep` and `fit`
(`--polydispersity 0.05` for `--option polydispersity=0.05`), read from the
protocol's signatures, docstrings and `OPTION_RANGES`."""

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
    """`{name: options.Option}`: the options of `protocol` that `command` takes
    as flags of their own: for `pile`, those of the protocol's `run` and set-up
    that no generic flag (`--seed`, `--max-steps`, ...) sets; for `sweep` and
    `fit`, the set-up options a batch takes. Options without a type the
    command line can give (a dict, no default and no range) stay `--option`'s."""
    from jaxpile import sweep
    from jaxpile.protocols import PROTOCOLS, options

    module = PROTOCOLS.get(protocol)
    if module is None or not hasattr(module, "run") or command not in DEFAULT_PROTOCOL:
        return {}
    if command == "pile":
        names = options.accepted(module) - set(module.CLI.flags.values()) - {"seed"}
    else:
        names = sweep.adapter(protocol).options & options.accepted(module)
    return {k: o for k, o in options.declared(module, names).items() if o.default is not None or o.range is not None}


def add_protocol_flags(parser, command: str, protocol: str) -> None:
    """One `--NAME` flag per option of `protocol` (`protocol_flags`), in a group
    of `--help` of their own, each with its docstring's help, range and default.
    A name the command already has a flag for keeps that flag."""
    flags = {k: o for k, o in protocol_flags(command, protocol).items()
             if o.flag not in parser._option_string_actions}
    if not flags:
        return
    group = parser.add_argument_group(f"options of the {protocol} protocol (the same as --option NAME=VALUE)")
    for o in flags.values():
        words = [o.help or o.name.replace("_", " ")]
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
