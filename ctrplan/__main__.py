"""``python -m ctrplan``: the ``ctrplan`` command (`ctrplan.cli.console.run`)."""

from ctrplan.cli.console import run

if __name__ == "__main__":
    run()
