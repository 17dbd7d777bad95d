"""The click classes the orthomvp commands are built from: options that take several values
(``--camera A B``), mutually exclusive options, and a group that lists its commands in the
order they were added."""

from __future__ import annotations

import importlib
from collections.abc import Iterable, Iterator, MutableMapping, Sequence
from typing import Any

import click
from click.core import ParameterSource


class Variadic(click.Option):
    """An option that takes one or more values: ``--camera A B`` is ``--camera A --camera B``
    (values run up to the next option; both spellings may be mixed). Needs :class:`Command`."""

    def __init__(self, param_decls: Sequence[str], **attrs: Any) -> None:
        super().__init__(param_decls, multiple=True, **attrs)


class Command(click.Command):
    """A command with :class:`Variadic` options and ``exclusive`` groups of option names of
    which at most one may be given."""

    def __init__(self, *args: Any, exclusive: Iterable[Sequence[str]] = (), **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.exclusive = tuple(tuple(group) for group in exclusive)

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        """Parse after spelling out variadic options; then check the exclusive groups."""
        names = {o for p in self.params if isinstance(p, Variadic) for o in p.opts}
        rest = super().parse_args(ctx, spell_out(args, names))
        by_name = {p.name: p for p in self.params}
        for group in self.exclusive:
            given = [
                by_name[name]
                for name in group
                if ctx.get_parameter_source(name) is ParameterSource.COMMANDLINE
            ]
            if len(given) > 1:
                first, second = (max(p.opts, key=len) for p in given[:2])
                raise click.UsageError(f"{second} is not allowed with {first}", ctx)
        return rest


def spell_out(args: list[str], names: set[str]) -> list[str]:
    """``args`` with every further value after an option of ``names`` given its own option:
    ``--eps 1 2 -o x`` becomes ``--eps 1 --eps 2 -o x``. A value is any word that does not
    start with ``-``, or a number; ``--`` ends the options."""
    out: list[str] = []
    i = 0
    while i < len(args):
        word = args[i]
        if word == "--":
            return out + args[i:]
        out.append(word)
        i += 1
        if word in names and i < len(args):
            out.append(args[i])  # the first value is click's, whatever it is
            i += 1
            while i < len(args) and _is_value(args[i]):
                out += [word, args[i]]
                i += 1
    return out


def _is_value(word: str) -> bool:
    if not word.startswith("-"):
        return True
    try:
        float(word)
    except ValueError:
        return False
    return True


class Group(click.Group):
    """A command group that lists its commands in the order they were added."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(self.commands)


class LazyCommands(MutableMapping[str, click.Command]):
    """A group's commands by name, in order, each imported from its module at first use: a
    run imports its own command's module, not every other's (:class:`Group`'s ``commands``).
    ``where`` maps each name to the (module, attribute) holding the command; commands added
    later (``add_command``) are held as they are."""

    def __init__(self, where: dict[str, tuple[str, str]]) -> None:
        self._where = dict(where)
        self._loaded: dict[str, click.Command] = {}

    def __getitem__(self, name: str) -> click.Command:
        if name not in self._loaded:
            module, attribute = self._where[name]  # (KeyError: no such command)
            self._loaded[name] = getattr(importlib.import_module(module), attribute)
        return self._loaded[name]

    def __setitem__(self, name: str, command: click.Command) -> None:
        self._where[name] = ("", "")
        self._loaded[name] = command

    def __delitem__(self, name: str) -> None:
        del self._where[name]
        self._loaded.pop(name, None)

    def __iter__(self) -> Iterator[str]:
        return iter(self._where)

    def __len__(self) -> int:
        return len(self._where)
