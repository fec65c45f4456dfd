"""`ctrplan train` / `ctrplan eval-model` without the planning commands, whose OMPL and FCL
dependencies GPU machines may lack. Same arguments as the CLI, e.g.

    python scripts/train_pinn.py train --recipe fast --device cuda --time-limit 9 --set dense_batch=16384
"""

from ctrplan.cli import eval_model, model  # noqa: F401  (importing them registers train and eval-model)
from ctrplan.cli.app import app

if __name__ == "__main__":
    app()
