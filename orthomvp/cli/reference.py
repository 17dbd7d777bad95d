"""The command-line reference (``docs/cli.md``), made from the commands' own help so that it
cannot drift from them: ``python -m orthomvp.cli.reference > docs/cli.md`` writes it, and
``tests/test_cli_reference.py`` checks that the file is what this module makes."""

from __future__ import annotations

import click

WIDTH = 100
"""The help's line width in the reference (click wraps to the terminal otherwise)."""


def _help(command: click.Command, name: str, parent: click.Context | None) -> str:
    """``command``'s ``--help`` text as ``orthomvp ... --help`` prints it at :data:`WIDTH`."""
    ctx = click.Context(
        command,
        info_name=name,
        parent=parent,
        terminal_width=WIDTH,
        max_content_width=WIDTH,
        **command.context_settings,
    )
    return command.get_help(ctx)


def markdown() -> str:
    """The reference: the group's help, then each command's, in the order ``--help`` lists them."""
    from orthomvp.cli import cli

    ctx = click.Context(cli, info_name="orthomvp", **cli.context_settings)
    parts = [
        "# Command-line reference",
        "",
        "Made by `python -m orthomvp.cli.reference > docs/cli.md` from the commands' own "
        "`--help`; do not edit by hand.",
        "",
        "```text",
        _help(cli, "orthomvp", None),
        "```",
    ]
    for name in cli.list_commands(ctx):
        command = cli.get_command(ctx, name)
        parts += ["", f"## orthomvp {name}", "", "```text", _help(command, name, ctx), "```"]
        if isinstance(command, click.Group):
            sub_ctx = click.Context(command, info_name=name, parent=ctx)
            for sub in command.list_commands(sub_ctx):
                text = _help(command.get_command(sub_ctx, sub), sub, sub_ctx)
                parts += ["", f"### orthomvp {name} {sub}", "", "```text", text, "```"]
    return "\n".join(parts) + "\n"


if __name__ == "__main__":
    print(markdown(), end="")
