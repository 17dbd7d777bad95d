"""The ``orthomvp`` command line: a click group with one module per command (or small group of
commands), which share the arguments and options of :mod:`orthomvp.cli.options`.

Every error is one line on stderr, and the exit status says what kind it was:

- 0: done;
- 1: an internal error (a bug: ``orthomvp: internal error: ...``; ``ORTHOMVP_DEBUG=1`` shows
  the traceback) or running out of memory;
- 2: a user error: a bad command line (``orthomvp: error: COMMAND: message``), or an error the
  library reports (bad files, impossible geometry, an output that cannot be written:
  ``orthomvp: error: message``);
- 130 on Ctrl-C (SIGINT), 143 on SIGTERM (as sent by ``timeout``, batch schedulers and Dask's
  nanny), 129 on SIGHUP (a closed terminal or SSH session): ``orthomvp: interrupted; no
  partial output was kept`` (any temporary output whose clean-up the signal cut short is
  removed first). SIGTERM and SIGHUP raise :class:`Terminated`, a ``KeyboardInterrupt``, so
  that everything that cleans up on Ctrl-C (the atomic outputs' temporary files, thread
  pools) cleans up on them too.

Python warnings are printed as one line each, ``orthomvp: warning: message``.
"""

from __future__ import annotations

import atexit
import gc
import importlib
import os
import signal
import sys
import threading
import time
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from types import FrameType, ModuleType

import click

from orthomvp import __version__
from orthomvp.cli.command import Group, LazyCommands
from orthomvp.cli.options import quiet_option
from orthomvp.errors import OrthoMVPError

CONTEXT_SETTINGS = {"help_option_names": ["-h", "--help"], "show_default": True}
EXIT_INTERNAL, EXIT_USER, EXIT_SIGINT = 1, 2, 130
TERMINATING = (signal.SIGTERM, signal.SIGHUP)
"""The signals that raise :class:`Terminated` while :func:`main` runs."""


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (``signum``), raised in the main thread while :func:`main` runs."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__()
        self.signum = signum


@click.group(cls=Group, context_settings=CONTEXT_SETTINGS, invoke_without_command=True)
@click.version_option(__version__, prog_name="orthomvp", message="%(prog)s %(version)s")
@quiet_option
@click.pass_context
def cli(ctx: click.Context, quiet: bool) -> None:
    """Occlusion-aware orthorectification and multi-view DEM refinement for planetary images.

    Run 'orthomvp COMMAND --help' for a command's arguments and options.
    """
    if ctx.invoked_subcommand is None:  # like rio: a usage error (stderr, exit 2), in one line
        raise click.UsageError("no command given; 'orthomvp --help' lists the commands")


def quiet_first(args: list[str]) -> list[str]:
    """``args`` with ``-q``/``--quiet`` given after the command (before any ``--``) moved in
    front of it, where the group takes it: ``orthomvp ortho ... -q`` as ``orthomvp -q ortho``."""
    end = args.index("--") if "--" in args else len(args)
    quiet = [a for a in args[:end] if a in ("-q", "--quiet")]
    if not quiet:
        return args
    return ["-q", *(a for a in args[:end] if a not in ("-q", "--quiet")), *args[end:]]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line on ``argv`` (default: ``sys.argv[1:]``); returns the exit status
    (see the module docstring).

    This is click's ``main`` with ``standalone_mode=False`` taken one step further: the context
    is made and invoked here, so that every error, Ctrl-C and SIGTERM included, is reported
    below as one line (click would turn Ctrl-C into an Abort after writing a blank line).
    """
    args = quiet_first(sys.argv[1:] if argv is None else [str(arg) for arg in argv])
    if "orthomvp.io.outputs" in sys.modules:  # the outputs of an earlier command of this process
        sys.modules["orthomvp.io.outputs"].written.clear()
    with sigterm_raises(), one_line_warnings():
        try:
            with cli.make_context("orthomvp", args) as ctx:
                cli.invoke(ctx)
            if _terminated:  # raised where Python drops it (a __del__, a callback): not lost
                raise Terminated(_terminated[0])
        except click.exceptions.Exit as exc:  # --help, --version
            return exc.exit_code
        except click.UsageError as exc:
            where = exc.ctx.command_path.partition(" ")[2] if exc.ctx else ""
            return _error(f"{where}: {exc.format_message()}" if where else exc.format_message())
        except click.ClickException as exc:
            return _error(exc.format_message())
        except OrthoMVPError as exc:
            return _error(exc)
        except OSError as exc:  # from a library below us, e.g. a file that vanished
            return _error(_os_error_text(exc))
        except (KeyboardInterrupt, click.exceptions.Abort) as exc:
            _remove_temporaries()
            print(f"orthomvp: interrupted; {_kept()}", file=sys.stderr)
            return 128 + exc.signum if isinstance(exc, Terminated) else EXIT_SIGINT
        except MemoryError as exc:
            return _error(
                f"out of memory ({exc or 'an allocation failed'}): try a smaller grid, window "
                "or image",
                EXIT_INTERNAL,
            )
        except Exception as exc:  # a bug, not a user error: still one line, unless debugging
            if os.environ.get("ORTHOMVP_DEBUG"):
                raise
            text = " ".join(f"{type(exc).__name__}: {exc}".split())
            print(
                f"orthomvp: internal error: {text[:300]}; rerun with ORTHOMVP_DEBUG=1 for a "
                "traceback and please report it",
                file=sys.stderr,
            )
            return EXIT_INTERNAL
    return 0


def _remove_temporaries() -> None:
    """:func:`orthomvp.io.outputs.remove_temporaries`, when that module was imported (``--help``
    and usage errors do not import it)."""
    outputs = sys.modules.get("orthomvp.io.outputs")
    if outputs is not None:
        outputs.remove_temporaries()


def _kept() -> str:
    """What an interrupt left: the outputs already complete (an interrupt while the command
    ended, a Dask cluster stopping say), or nothing partial."""
    outputs = sys.modules.get("orthomvp.io.outputs")
    done = outputs.written if outputs is not None else []
    if not done:
        return "no partial output was kept"
    return f"the outputs were already complete: {', '.join(map(str, done))}"


def _error(message: object, status: int = EXIT_USER) -> int:
    """Report ``message`` as one line on stderr; returns ``status``."""
    text = " ".join(str(message).split())
    print(f"orthomvp: error: {text}", file=sys.stderr)
    return status


def _os_error_text(exc: OSError) -> str:
    """``PATH: cause`` of an OSError that names a file, the cause alone otherwise (never the
    raw ``[Errno N]`` text)."""
    if not exc.strerror:
        return str(exc)
    cause = f"{exc.strerror[:1].lower()}{exc.strerror[1:]}"
    return f"{exc.filename}: {cause}" if exc.filename is not None else cause


_terminated: list[int] = []
"""The SIGTERM received (at most one), even when its :class:`Terminated` was raised where
Python prints and drops exceptions (a ``__del__``, say)."""


def _raise_terminated(signum: int, frame: FrameType | None) -> None:
    # once: a second signal must not interrupt the clean-up that the first one started
    for sig in TERMINATING:
        signal.signal(sig, signal.SIG_IGN)
    _terminated.append(signum)
    raise Terminated(signum)


RESEND_SECONDS = 0.05
"""How long after an interrupt was dropped (in a ``__del__``) it is sent again."""


def _resend(signum: int) -> None:
    """Send ``signum`` to this process again after :data:`RESEND_SECONDS`."""
    time.sleep(RESEND_SECONDS)
    os.kill(os.getpid(), signum)


@contextmanager
def sigterm_raises() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP (:data:`TERMINATING`) raise :class:`Terminated` in
    the main thread (elsewhere signals cannot be handled, and nothing changes), and an
    interrupt that Python drops (raised in a ``__del__``) prints nothing (:func:`main` reports
    a dropped one itself); the previous handlers come back after. A signal ignored when the
    block starts (``nohup``) stays ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.getsignal(sig) for sig in TERMINATING}
    for sig, handler in previous.items():
        if handler != signal.SIG_IGN:
            signal.signal(sig, _raise_terminated)
    _terminated.clear()
    hook = sys.unraisablehook

    def unraisable(info: object) -> None:  # an interrupt dropped in a __del__, say
        exc = getattr(info, "exc_value", None)
        if isinstance(exc, Terminated):  # delivered again, to the main thread's own code
            # sent a moment later from another thread (the handlers still ignore it while
            # the thread starts), once this hook and its __del__ are left
            threading.Thread(target=_resend, args=(exc.signum,), daemon=True).start()
            for sig, handler in previous.items():
                if handler != signal.SIG_IGN:
                    signal.signal(sig, _raise_terminated)
        elif not isinstance(exc, KeyboardInterrupt):
            hook(info)  # type: ignore[arg-type]

    sys.unraisablehook = unraisable
    try:
        yield
    finally:
        for sig, handler in previous.items():
            if handler is not None:
                signal.signal(sig, handler)
        sys.unraisablehook = hook


@contextmanager
def one_line_warnings() -> Iterator[None]:
    """Within the block, warnings print as ``orthomvp: warning: message`` (one line, no
    source path)."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:  # noqa: ANN001
        text = " ".join(str(message).split())
        print(f"orthomvp: warning: {text}", file=file or sys.stderr)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


GC_THRESHOLD = 50_000
"""Allocations between the command's young-generation garbage collections (Python's default:
700). A command's data are numpy arrays, which the collector does not track; what it tracks
is mostly the imported modules' objects, which it went through about 100 times in a 24 m
ngi-aerial orthophoto (13 ms of 0.34 s) and 250 in a 3 m mosaic (70 ms). The 1.5 m mosaic's
peak memory is the same (0.77-0.80 GB)."""


def standard_streams() -> None:
    """Open file descriptors 0, 1 and 2 on the null device where they are closed (``>&-``,
    ``2>&-``), and point ``sys.stdin``, ``sys.stdout`` and ``sys.stderr`` there where Python
    set them to None for it: so no file the command opens takes their number (what GDAL or a
    print writes would land in it), the messages of a closed stream are dropped (an error is
    not printed on stdout instead of a closed stderr: ``print(file=None)`` would), and the exit
    status is the command's. File names that are not UTF-8 are printed as their bytes."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:  # closed: the lowest free number, fd itself (0 .. fd-1 are open)
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
    for fd, name, mode in ((0, "stdin", "r"), (1, "stdout", "w"), (2, "stderr", "w")):
        if getattr(sys, name) is None:
            setattr(sys, name, open(fd, mode, closefd=False))  # noqa: SIM115 (for the process)
    for stream in (sys.stdout, sys.stderr):  # file names that are not UTF-8, byte for byte
        with suppress(AttributeError, ValueError):
            stream.reconfigure(errors="surrogateescape")


def main_entry() -> None:
    """Console-script entry point. The objects of the imports so far are left out of garbage
    collection (``gc.freeze``: they live as long as the process), and young objects are
    collected every :data:`GC_THRESHOLD` allocations. Once the command is done, its output
    flushed and the exit handlers run, the process ends without Python's teardown of every
    module (``os._exit``): unloading numpy, GDAL, OpenCV and Embree took 60 ms of a 0.45 s
    orthophoto. A command that left a thread running ends the usual way, which waits for it."""
    standard_streams()
    gc.freeze()
    gc.set_threshold(GC_THRESHOLD, *gc.get_threshold()[1:])
    code = main()
    if threading.active_count() > 1:
        sys.exit(code)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with suppress(OSError, ValueError):  # a closed pipe, a closed stream
            stream.flush()
    os._exit(code)


COMMANDS = {
    "demo": ("orthomvp.cli.demo", "demo"),
    "info": ("orthomvp.cli.info", "info"),
    "synth": ("orthomvp.cli.synth", "synth"),
    "mesh": ("orthomvp.cli.mesh", "mesh"),
    "render": ("orthomvp.cli.render", "render"),
    "visibility": ("orthomvp.cli.ortho", "visibility"),
    "ortho": ("orthomvp.cli.ortho", "ortho"),
    "mosaic": ("orthomvp.cli.ortho", "mosaic"),
    "explore": ("orthomvp.cli.explore", "explore"),
    "fit": ("orthomvp.cli.fit", "fit"),
    "eps-study": ("orthomvp.cli.eps_study", "eps_study"),
    "check": ("orthomvp.cli.check", "check"),
    "isd": ("orthomvp.cli.isd", "isd"),
    "bench": ("orthomvp.cli.bench", "bench"),
    "view": ("orthomvp.cli.view", "view"),
}
"""Each command's (module, attribute), in the order --help lists them."""


def __getattr__(name: str) -> ModuleType:
    """The command modules (``orthomvp.cli.bench``, ...), imported when first asked for."""
    if f"{__name__}.{name}" in {module for module, _ in COMMANDS.values()}:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


cli.commands = LazyCommands(COMMANDS)
