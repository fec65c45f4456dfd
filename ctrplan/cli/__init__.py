"""Command-line interface. One module per command group; `main` turns user errors into exit 2.

Contracts (DESIGN.md §3): bad input -> one line on stderr naming file/row/field, exit code 2, no
traceback, nothing half-written; ``--json`` prints one JSON document on stdout and nothing else.
"""

from __future__ import annotations

import sys

import typer

from ctrplan import __version__
from ctrplan.errors import InputError

app = typer.Typer(
    name="ctrplan",
    help="Motion planning for concentric-tube robots (Cosserat-rod and PINN kinematics, FCL, OMPL).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
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


def _register() -> None:
    # Command modules attach themselves to `app` on import.
    from ctrplan.cli import kinematics  # noqa: F401


def main(argv: list[str] | None = None) -> int:
    """Console entry point: exit 2 with one clear line for any `InputError`."""
    _register()
    try:
        app(args=argv, standalone_mode=False)
    except InputError as exc:
        print(f"ctrplan: error: {exc}", file=sys.stderr)
        return 2
    except typer.Exit as exc:
        return exc.exit_code
    except (typer.Abort, KeyboardInterrupt):
        print("ctrplan: aborted", file=sys.stderr)
        return 130
    except Exception as exc:  # click usage errors
        import click

        if isinstance(exc, click.ClickException):
            exc.show()
            return 2
        raise
    return 0


if __name__ == "__main__":
    sys.exit(main())
