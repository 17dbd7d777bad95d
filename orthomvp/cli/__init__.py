"""The ``orthomvp`` command line: a click group with one module per command (or small group of
commands), which share the arguments and options of :mod:`orthomvp.cli.options`.

Every user error becomes one line on stderr and exit status 2: usage errors as
``orthomvp: error: COMMAND: message``, errors the library reports (bad files, impossible
geometry) as ``orthomvp: error: message``. Ctrl-C exits with 130. Outputs are written
atomically, so a failed command leaves nothing half-written.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

import click

from orthomvp import __version__
from orthomvp.cli.command import Group
from orthomvp.cli.options import quiet_option
from orthomvp.errors import OrthoMVPError

CONTEXT_SETTINGS = {"help_option_names": ["-h", "--help"], "show_default": True}


@click.group(cls=Group, context_settings=CONTEXT_SETTINGS, invoke_without_command=True)
@click.version_option(__version__, prog_name="orthomvp", message="%(prog)s %(version)s")
@quiet_option
@click.pass_context
def cli(ctx: click.Context, quiet: bool) -> None:
    """Occlusion-aware orthorectification and multi-view DEM refinement for planetary images.

    Run 'orthomvp COMMAND --help' for a command's arguments and options.
    """
    if ctx.invoked_subcommand is None:
        click.echo(ctx.get_help())
        ctx.exit(2)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line on ``argv`` (default: ``sys.argv[1:]``); returns the exit status.

    This is click's ``main`` with ``standalone_mode=False`` taken one step further: the context
    is made and invoked here, so that every error, Ctrl-C included, is reported below as one
    line (click would turn Ctrl-C into an Abort after writing a blank line).
    """
    args = sys.argv[1:] if argv is None else [str(arg) for arg in argv]
    try:
        with cli.make_context("orthomvp", args) as ctx:
            cli.invoke(ctx)
    except click.exceptions.Exit as exc:  # --help, --version, or no command
        return exc.exit_code
    except click.UsageError as exc:
        where = exc.ctx.command_path.partition(" ")[2] if exc.ctx else ""
        return _error(f"{where}: {exc.format_message()}" if where else exc.format_message())
    except (click.ClickException, OrthoMVPError, OSError) as exc:
        return _error(exc.format_message() if isinstance(exc, click.ClickException) else exc)
    except KeyboardInterrupt:
        print("orthomvp: interrupted; no partial output was kept", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug, not a user error: still one line, unless debugging
        if os.environ.get("ORTHOMVP_DEBUG"):
            raise
        return _error(
            f"internal error ({type(exc).__name__}: {exc}); rerun with ORTHOMVP_DEBUG=1 for a "
            "traceback and please report it"
        )
    return 0


def _error(message: object) -> int:
    """Report ``message`` as one line on stderr; the exit status of user errors."""
    text = " ".join(str(message).splitlines())
    print(f"orthomvp: error: {text}", file=sys.stderr)
    return 2


def main_entry() -> None:
    """Console-script entry point."""
    sys.exit(main())


# the commands, in the order --help lists them
from orthomvp.cli import (  # noqa: E402
    bench,
    demo,
    eps_study,
    explore,
    fit,
    mesh,
    ortho,
    render,
    synth,
)

for _command in (
    demo.demo,
    synth.synth,
    mesh.mesh,
    render.render,
    ortho.visibility,
    ortho.ortho,
    ortho.mosaic,
    explore.explore,
    fit.fit,
    eps_study.eps_study,
    bench.bench,
):
    cli.add_command(_command)
