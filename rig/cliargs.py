"""How the ``rig`` command line reads its arguments, the same way on every command.

- The options several commands share (``SHARED``: ``--bus``, ``--channel``, ``--bench``,
  ``--out``, ``--timeout``, ``--quiet``) are spelled once, here, and each command says which
  it takes and with what default (``add_shared``). A shared option is accepted before the
  command or after it, at any level: ``rig --bus unixcan param list``, ``rig param --bus
  unixcan list`` and ``rig param list --bus unixcan`` are the same; given where the command
  does not take it, it is a usage error of that command.
- A usage error is the command's own: its usage line and message (``rig run: error: ...``),
  with the nearest spelling for an unknown option or command ("did you mean --channel?"),
  exit status 2.
- Values are checked where they are read: a channel is a plain name (``channel``), a time
  or a count is a finite number in its range (``number``), a window is ``T0,T1`` with
  T0 < T1 (``window``).
"""

from __future__ import annotations

import argparse
import difflib
import math
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NoReturn

SHARED_KEY = "_rig_shared"  # the namespace attribute: {dest: Shared} of the chosen command
PARSER_KEY = "_rig_parser"  # the namespace attribute: the chosen command's parser


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors suggest the nearest option or command: at the two
    places argparse finds them (a value outside an argument's choices: ``_check_value``;
    arguments left over: ``parse_args``), with difflib. (argparse's own ``suggest_on_error``
    comes with Python 3.14; the rig runs on 3.11.)"""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.register("action", "parsers", Subcommands)

    def option_strings(self) -> list[str]:
        return [s for a in self._actions for s in a.option_strings]

    def parse_args(self, args: Sequence[str] | None = None,  # type: ignore[override]
                   namespace: argparse.Namespace | None = None) -> argparse.Namespace:
        ns, extras = self.parse_known_args(args, namespace)
        if extras:
            self.unrecognized(extras)
        return ns

    def unrecognized(self, extras: Sequence[str]) -> NoReturn:
        given = extras[0].split("=", 1)[0]
        hint = nearest(given, self.option_strings()) if given.startswith("-") else None
        self.error(f"unrecognized arguments: {' '.join(extras)}" + _hint(hint))

    def _check_value(self, action: argparse.Action, value: Any) -> None:
        if action.choices is not None and value not in action.choices:
            choices = ", ".join(map(repr, action.choices))
            raise argparse.ArgumentError(
                action, f"invalid choice: {value!r} (choose from {choices})"
                + _hint(nearest(str(value), [str(c) for c in action.choices])))
        super()._check_value(action, value)


def _hint(near: str | None) -> str:
    return f" (did you mean {near}?)" if near else ""


class Subcommands(argparse._SubParsersAction):  # type: ignore[type-arg]
    """Sub-commands whose leftover arguments are an error of the sub-command itself (its
    usage, its options suggested), not of ``rig`` (the top-level usage)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        name, arg_strings = values[0], values[1:]
        choice = self._name_parser_map.get(name)
        if choice is None:
            choices = ", ".join(map(repr, self._name_parser_map))
            parser.error(f"argument {self.metavar or self.dest}: invalid choice: {name!r} "
                         f"(choose from {choices})"
                         + _hint(nearest(name, list(self._name_parser_map))))
        if self.dest is not argparse.SUPPRESS:
            setattr(namespace, self.dest, name)
        sub, extras = choice.parse_known_args(arg_strings, None)
        if extras:
            if isinstance(choice, Parser):
                choice.unrecognized(extras)
            choice.error(f"unrecognized arguments: {' '.join(extras)}")
        for key, value in vars(sub).items():
            setattr(namespace, key, value)


def nearest(given: str, candidates: Sequence[str]) -> str | None:
    found = difflib.get_close_matches(given, list(candidates), n=1, cutoff=0.6)
    return found[0] if found else None


# -- values ------------------------------------------------------------------------------

def channel(text: str) -> str:
    """A bus channel: a plain name (what both transports accept: letters, digits, ``_ - .``,
    1 to 63 characters, not starting with ``.`` or ``-``)."""
    from rig.bus.unixcan import channel_name_ok

    if not channel_name_ok(text):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a channel name: 1 to 63 letters, digits, '_', '-' or '.', not "
            "starting with '.' or '-'")
    return text


def number(kind: Callable[[str], float] = float, *, minimum: float | None = None,
           above: float | None = None, maximum: float | None = None,
           unit: str = "") -> Callable[[str], Any]:
    """A finite number (``float`` or ``int``) within bounds: ``minimum <= x``, ``above < x``,
    ``x <= maximum``."""

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {_kind_name(kind)}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
        bounds = []
        if minimum is not None and value < minimum:
            bounds.append(f">= {minimum:g}")
        if above is not None and value <= above:
            bounds.append(f"> {above:g}")
        if maximum is not None and value > maximum:
            bounds.append(f"<= {maximum:g}")
        if bounds:
            raise argparse.ArgumentTypeError(
                f"{text}{unit and ' ' + unit} is out of range: it must be {' and '.join(bounds)}")
        return value

    parse.__name__ = _kind_name(kind)  # argparse names the type in its messages
    return parse


def _kind_name(kind: Callable[[str], float]) -> str:
    return "an integer" if kind is int else "a number"


def port(text: str) -> int:
    """A TCP port, 1 to 65535."""
    return int(number(int, minimum=1, maximum=65535)(text))


def window(text: str) -> tuple[float, float]:
    """``T0,T1`` in seconds, finite, 0 <= T0 < T1."""
    a, sep, b = text.partition(",")
    if not sep:
        raise argparse.ArgumentTypeError(f"{text!r}: expected T0,T1 (seconds)")
    t0 = number(minimum=0.0)(a.strip())
    t1 = number(minimum=0.0)(b.strip())
    if not t0 < t1:
        raise argparse.ArgumentTypeError(f"{text!r}: the window must end after it starts "
                                         "(T0 < T1)")
    return (t0, t1)


# -- options shared by several commands --------------------------------------------------

@dataclass(frozen=True)
class Option:
    flags: tuple[str, ...]
    dest: str
    metavar: str | None = None
    type: Callable[[str], Any] | None = None
    flag: bool = False  # store_true
    # the environment variable that stands in for it on every command that takes it (checked
    # by that command's rules: HIL_BUS=bogus is a usage error, not a traceback later)
    env: str | None = None


SHARED: dict[str, Option] = {o.dest: o for o in (
    Option(("--bus",), "bus", metavar="BUS", env="HIL_BUS"),
    Option(("--channel",), "channel", metavar="NAME", type=channel),
    Option(("--bench",), "bench", metavar="FILE"),
    Option(("--out",), "out", metavar="DIR"),
    Option(("--timeout",), "timeout", metavar="S", type=number(above=0.0, unit="s")),
    Option(("--quiet",), "quiet", flag=True),
)}
BUS_TRANSPORTS = ("auto", "socketcan", "unixcan")
BUS_WITH_INPROC = (*BUS_TRANSPORTS, "inproc")


@dataclass(frozen=True)
class Shared:
    """How one command takes a shared option: its default, choices and value type."""

    default: Any = None
    choices: tuple[str, ...] | None = None
    type: Callable[[str], Any] | None = None
    env: str | None = None  # the environment variable that stands in for it (checked too)
    required: bool = False


def add_shared(parser: argparse.ArgumentParser, dest: str, *, help: str | None = None,
               default: Any = None, choices: Sequence[str] | None = None,
               type: Callable[[str], Any] | None = None, env: str | None = None,
               required: bool = False, container: Any = None) -> None:
    """Lets ``parser`` take the shared option ``dest`` (``SHARED``), with its own default,
    choices and help (in ``container``, a group of it, when given). Given before the command,
    the value is checked here the same way; ``required`` is checked once the command is
    known (the option may come before it)."""
    opt = SHARED[dest]
    kwargs: dict[str, Any] = {"dest": dest, "default": argparse.SUPPRESS, "help": help}
    if opt.flag:
        kwargs["action"] = "store_true"
    else:
        kwargs["metavar"] = opt.metavar
        kwargs["type"] = type or opt.type
        if choices is not None:
            kwargs["choices"] = tuple(choices)
    (container or parser).add_argument(*opt.flags, **kwargs)
    taken: dict[str, Shared] = dict(parser.get_default(SHARED_KEY) or {})
    taken[dest] = Shared(default, tuple(choices) if choices is not None else None,
                         type or opt.type, env or opt.env, required)
    parser.set_defaults(**{SHARED_KEY: taken, PARSER_KEY: parser})


def verb(sub: argparse._SubParsersAction, name: str, *, help: str,  # type: ignore[type-arg]
         description: str, epilog: str | None = None) -> argparse.ArgumentParser:
    """Adds the command ``name`` to ``sub``: its line in the list of commands (``help``), what
    it does (``description``) and what follows its options (``epilog``). An epilog written on
    several lines (the steps, the outputs, the exit statuses) is printed as written, and the
    description with it; a one-line epilog is wrapped to the terminal like the rest."""
    laid_out = epilog is not None and "\n" in epilog
    return sub.add_parser(name, help=help, description=description, epilog=epilog,
                          formatter_class=argparse.RawDescriptionHelpFormatter if laid_out
                          else argparse.HelpFormatter)


def command(parser: argparse.ArgumentParser, func: Callable[[argparse.Namespace], int]
            ) -> None:
    """Marks ``parser`` as a command (a leaf) that runs ``func``."""
    parser.set_defaults(func=func, **{PARSER_KEY: parser})
    if parser.get_default(SHARED_KEY) is None:
        parser.set_defaults(**{SHARED_KEY: {}})


def add_top_level(parser: argparse.ArgumentParser) -> None:
    """The shared options before any command (checked against the command chosen)."""
    group = parser.add_argument_group(
        "options of several commands", "accepted before the command or after it; what each "
        "means and its default: rig COMMAND --help")
    for opt in SHARED.values():
        kwargs: dict[str, Any] = {"dest": opt.dest, "default": None}
        if opt.flag:
            kwargs["action"] = "store_true"
        else:
            kwargs["metavar"] = opt.metavar
        group.add_argument(*opt.flags, **kwargs)


def finish(ns: argparse.Namespace) -> argparse.Namespace:
    """After parsing: each shared option the command takes gets its value (given anywhere,
    checked by the command's rules) or the command's default; one it does not take but was
    given is that command's usage error; an invalid ``HIL_CHANNEL`` is one too."""
    parser: argparse.ArgumentParser | None = getattr(ns, PARSER_KEY, None)
    taken: dict[str, Shared] = getattr(ns, SHARED_KEY, None) or {}
    for dest, opt in SHARED.items():
        value = getattr(ns, dest, None)
        rule = taken.get(dest)
        given = value is not None and value is not False
        if rule is None:
            if given and parser is not None:
                parser.error(f"{opt.flags[0]} does not apply to this command")
            continue
        if value is None and rule.required and parser is not None:
            parser.error(f"the following arguments are required: {opt.flags[0]}")
        if value is None:
            value = rule.default
        elif isinstance(value, str) and not opt.flag:
            value = _checked(parser, opt, rule, value)
        elif opt.flag:
            value = bool(value)
        setattr(ns, dest, value)
        if value is None and rule.env and os.environ.get(rule.env) is not None:
            _checked(parser, opt, rule, os.environ[rule.env], source=rule.env)
    for key in (SHARED_KEY, PARSER_KEY):
        if hasattr(ns, key):
            delattr(ns, key)
    return ns


def _checked(parser: argparse.ArgumentParser | None, opt: Option, rule: Shared, text: str,
             source: str | None = None) -> Any:
    """A value given before the command (still text) checked as the command checks it."""
    where = source or "/".join(opt.flags)
    fail: Callable[[str], NoReturn] = parser.error if parser is not None else _exit_usage
    if rule.choices is not None and text not in rule.choices:
        hint = nearest(text, rule.choices)
        fail(f"argument {where}: invalid choice: {text!r} (choose from "
             f"{', '.join(map(repr, rule.choices))})" + (f" (did you mean {hint}?)" if hint
                                                         else ""))
    if rule.type is None:
        return text
    try:
        return rule.type(text)
    except (argparse.ArgumentTypeError, ValueError) as exc:
        fail(f"argument {where}: {exc}")


def _exit_usage(message: str) -> NoReturn:
    print(f"rig: error: {message}", file=sys.stderr)
    raise SystemExit(2)
