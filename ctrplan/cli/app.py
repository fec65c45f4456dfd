"""The typer application of the command line; `main` turns user errors into exit 2.

Contracts (docs/design.md §3): bad input -> one line on stderr naming file/row/field, exit code 2, no
traceback, nothing half-written; ``--json`` prints one JSON document on stdout and nothing else.
"""

from __future__ import annotations

import importlib
import inspect
import sys
import warnings

import typer

from ctrplan import __version__
from ctrplan.base.errors import InputError
from ctrplan.cli import console
from ctrplan.cli.console import INTERRUPTED

#: Click settings of every command group: help as wide as the terminal, up to 120 columns.
HELP_SETTINGS = {"max_content_width": 120}

app = typer.Typer(
    name="ctrplan",
    help="Motion planning for concentric-tube robots (Cosserat-rod and PINN kinematics, FCL, OMPL).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # plain click help: wrapped, never cut with "…", no <bool> metavars
    context_settings=HELP_SETTINGS,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"ctrplan {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                 help="Print the version and exit."),
) -> None:
    """ctrplan: plan motions for concentric-tube robots through anatomy."""


#: The command modules, in the order `ctrplan --help` lists their commands (groups come last).
COMMAND_MODULES = ("kinematics", "design", "diagnose", "model", "eval_model", "plan", "roadmap", "serve",
                   "stability", "bench", "scene")


def _register() -> None:
    # Command modules attach themselves to `app` on import.
    for module in COMMAND_MODULES:
        importlib.import_module(f"ctrplan.cli.{module}")
    _full_short_help(app)


def _full_short_help(group: typer.Typer) -> None:
    """Command lists show each command's first docstring paragraph in full (click would cut it)."""
    for info in group.registered_commands:
        if info.short_help is None and info.callback is not None and info.callback.__doc__:
            info.short_help = inspect.cleandoc(info.callback.__doc__).split("\n\n")[0].replace("\n", " ")
    for sub in group.registered_groups:
        if sub.typer_instance is not None:
            _full_short_help(sub.typer_instance)


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"ctrplan: warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Run one command: exit 2 with one clear line for any `InputError` or usage error; Ctrl-C, at
    any moment, ends it with the one line ``ctrplan: aborted`` (exit 130, see `ctrplan.cli.console`)."""
    args = sys.argv[1:] if argv is None else list(argv)
    if args == ["--version"]:  # answer without importing the commands (torch, OMPL, ...)
        print(f"ctrplan {__version__}")
        return 0
    previous = console.catch_ctrl_c()
    try:
        code = _run(args)
    except BaseException as exc:
        if not (console.interrupted() or isinstance(exc, (KeyboardInterrupt, typer.Abort))):
            console.restore(previous)
            raise
        console.abort(exc)  # whatever the interrupt turned into on its way out
    if console.interrupted() or code == INTERRUPTED:  # typer returns Ctrl-C as this code
        console.abort()
    console.restore(previous)
    return code


def _run(args: list[str]) -> int:
    _register()
    warnings.showwarning = _one_line_warning
    try:
        code = app(args=args, standalone_mode=False)  # a command's typer.Exit(n) comes back as n
    except InputError as exc:
        print(f"ctrplan: error: {exc}", file=sys.stderr)
        return 2
    except typer.Exit as exc:
        return exc.exit_code
    except typer.TyperException as exc:  # usage errors (typer bundles its own click)
        message = exc.format_message()
        ctx = getattr(exc, "ctx", None)
        if ctx is not None and message == ctx.get_help():  # a group without arguments shows its help
            print(message)
        elif message:
            print(f"ctrplan: error: {message}", file=sys.stderr)
        return exc.exit_code
    return code if isinstance(code, int) else 0
