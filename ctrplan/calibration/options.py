"""The knobs of a diagnosis (`DiagnoseOptions`): shared by the procedure (`ctrplan.calibration.diagnosis`)
and the significance tests and cause selection it runs (`ctrplan.calibration.selection`)."""

from __future__ import annotations

from dataclasses import dataclass

from ctrplan.calibration.split import Split, split_rows
from ctrplan.model.causes import DEFAULT_CAUSES


@dataclass(frozen=True)
class DiagnoseOptions:
    """Knobs of the diagnosis (defaults are what the CLI uses)."""

    candidates: tuple[str, ...] = DEFAULT_CAUSES
    heldout: float = 0.25          # fraction of the rows held out ...
    heldout_last: bool = False     # ... the last ones in acquisition order (else contiguous blocks)
    seed: int = 0                  # seed of the held-out blocks
    pairs: int = 3                 # grow a cause set by trying this many partners (0: single causes only)
    grow_from: int = 2             # grow cause sets from this many best single causes
    max_causes: int = 4            # up to this many causes
    bic_margin: float = 10.0       # BIC must drop by more than this ("very strong" evidence)
    min_gain: float = 0.05         # and the held-out mean error by at least this fraction
    alpha: float = 0.01            # with this significance (one-sided Wilcoxon, held-out rows)
    outlier_mads: float = 8.0      # outlier: error > median + this many robust sigmas (and > 3 x median)
    max_nfev: int = 30
    max_rows: int = 1000           # larger files: this many rows in 20 contiguous runs spread over the file
    noise_tolerance: float = 1.3   # "within the noise": held-out mean error <= this x noise_mm
    resamples: int = 2             # other splits every significant candidate is refitted on (stability)
    resample_nfev: int = 10        # their fits start from the main fit: a few steps suffice
    stable_fraction: float = 2 / 3  # stable: significant on at least this share of the splits
    experiment_rows: int = 20      # configurations that separate tied explanations (experiment.csv)
    # causes also fitted as one more cause of the chosen set and of its best subset one cause smaller;
    # never named: contenders for a caller that chooses among them on rows of its own (the few-shot
    # stage's `best_predictor`)
    also_fit: tuple[str, ...] = ()

    def split(self, n: int) -> Split:
        """The main split of ``n`` rows."""
        return split_rows(n, self.heldout, last=self.heldout_last, seed=self.seed)
