"""The command line: one module per command group, the entry point and what the commands share.

`console` (the ``ctrplan`` entry point and its Ctrl-C handling, standard
library only, so it holds from the process's start), `app` (the typer application and `main`, which
turns user errors into exit 2), `options` and `progress` (what the commands share), and one module per
command group, each attaching its commands to `app.app`."""
