"""The command line: one module per command group, the entry point and what the commands share.

`console` (the ``ctrplan`` entry point and its Ctrl-C handling, standard
library only, so it holds from the process's start), `app` (the typer application and `main`, which
turns user errors into exit 2), `options` and `progress` (what the commands share), and one module per
command group, each attaching its commands to `app.app`."""

import os

#: torch's OpenMP threads wait for work without spinning. Beside other jobs on a shared machine,
#: spinning threads burn the cores they wait on: two-thread training beside ~8 other processes on
#: 2 cores ran 30 steps in 49-93 s spinning and in 4-7 s waiting passively (issue 40,
#: docs/benchmarks.md). Set before torch loads its OpenMP runtime; a value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
