"""The text report of a diagnosis (what `ctrplan diagnose` prints without ``--json``, and
``report.txt`` under ``--out``): rows and nominal error, the candidates, the verdict with the named
causes and their values, what is left, the sources of the plausible ranges cited. Rendered from the
diagnosis's JSON document (`Diagnosis.to_json`), computed once.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ctrplan.calibration.data import rows_text
from ctrplan.model.causes.base import PER_SESSION

if TYPE_CHECKING:
    from ctrplan.calibration.diagnosis import Diagnosis


def summary_text(diag: Diagnosis) -> str:
    """A human-readable report (the CLI prints it without --json)."""
    j = diag.to_json()
    return "\n".join(_rows(diag, j) + _candidates(diag, j) + _verdict(diag, j) + _tail(j))


def _rows(diag: Diagnosis, j: dict) -> list[str]:
    used = "" if j["rows_used"] == j["rows"] else (
        f", {j['rows_used']} used in contiguous runs ({j['rows_dropped']} dropped by max_rows)")
    m = j["distinct_configurations"]
    lines = [f"{diag.data.source}: {j['rows']} rows{used}, {m} distinct configuration{'s' * (m != 1)} "
             f"({j['train_rows']} train, {j['heldout']['how']}), tubes measured: "
             f"{j['tubes_measured']}"]
    if j["outside_domain_rows"]:
        lines.append(f"  note: {rows_text(j['outside_domain_rows'])} lie outside the snap-free "
                     f"planning domain (accepted)")
    if j["unsolved_rows"]:
        lines.append(f"  note: the nominal model does not solve {rows_text(j['unsolved_rows'])} "
                     f"(excluded)")
    lines.append("nominal model, held-out error per tube:")
    for t in j["nominal"]["per_tube"]:
        lines.append(f"  tube {t['tube']}: mean {t['mean_mm']:.3f} mm, median {t['median_mm']:.3f}, "
                     f"p95 {t['p95_mm']:.3f}, {t['mean_pct_length']:.2f} % of arc length")
    lines += [f"  where: {s}" for s in diag.where.get("findings", [])]
    return lines


def _candidates(diag: Diagnosis, j: dict) -> list[str]:
    splits = diag.selection.splits
    lines = [f"candidates (training BIC, held-out mean tip error, splits of {splits} where "
             f"significant; * significant on the main split):"]
    for c in sorted(diag.candidates, key=lambda c: c.fit.bic):
        ref = "" if c.reference == "nominal" else f" vs {c.reference}"
        bad = " IMPLAUSIBLE" if c.fit.implausible else ""
        bad += " UNRESOLVED" if c.fit.unresolved() else ""
        bad += " PAST-BOUND" if c.fit.pushed else ""
        lines.append(f"  {'*' if c.significant else ' '} {c.name:<34s} dBIC {c.delta_bic:10.1f}  "
                     f"held-out {c.heldout_mean(0):.3f} mm  gain {100 * c.main.gain:5.1f} %{ref}  "
                     f"{c.significant_splits()}/{splits}{bad}")
    lines += [f"  not fitted: {name} ({'; '.join(why)})" for name, why in j["not_fitted"].items()]
    fixed = {k: v for c in diag.candidates if len(c.causes) == 1 for k, v in c.fit.fixed.items()}
    if fixed:
        lines.append("  held at their file values (the data cannot show them):")
        lines += [f"    {k}: {v}" for k, v in fixed.items()]
    for title, key in (("implausible, not named", "implausible"), ("at its bound, not named",
                                                                    "pushed_past_bound")):
        lines += [f"  {title}: {name}: " + "; ".join(f"{k} {v}" for k, v in why.items())
                  for name, why in j[key].items()]
    lines += [f"  not resolved by the rows, not named: {name}: {', '.join(ps)}"
              for name, ps in j["unresolved"].items()]
    noise_mm = j["noise_mm"]
    noise_txt = "not estimated" if noise_mm is None else f"{noise_mm:.3f} mm mean tip error"
    lines.append(f"measurement noise: {noise_txt} ({j['noise']['method']})")
    return lines


def _verdict(diag: Diagnosis, j: dict) -> list[str]:
    nom, ext = j["nominal"], j["extended"]
    if diag.chosen is None:
        off = f"the nominal model is off by {nom['mean_mm']:.3f} mm"
        return [{"none": "cause: none -- the nominal model matches the held-out rows to the measurement "
                         "noise",
                 "undetermined": f"cause: undetermined -- {off}, but the rows cannot identify a cause: "
                                 f"{j['undetermined']}; nothing named, no extended robot",
                 "unexplained": f"cause: unexplained -- {off} (noise {_noise_text(j)}) and no plausible "
                                f"cause of the library beats it on the splits"}[j["cause"]]]
    lines = [f"cause: {' + '.join(_cause_text(c, diag.data.sessions) for c in diag.causes)}"]
    if j["ties"]:
        lines.append(f"  tie: {', '.join(j['ties'])} fit as well (neither is better on the held-out "
                     "rows, and the training BIC is within its margin or its preference does not "
                     "repeat there); the data do not tell them apart: the fewest parameters is named, "
                     "tentatively" + ("; experiment.csv lists configurations that separate them"
                                      if diag.experiment is not None else ""))
    if j["unstable"]:
        lines.append("  not named (significant on too few splits): " + ", ".join(j["unstable"]))
    lines += [_parameter_line(name, p) for name, p in j["parameters"].items()]
    if j["derived"]:
        lines.append("  i.e. " + ", ".join(f"{k} = " + ("not determined" if v is None else f"{v:.4g}")
                                           for k, v in j["derived"].items()))
    lines.append(f"held-out tip error: {nom['mean_mm']:.3f} -> {ext['mean_mm']:.3f} mm mean, "
                 f"{nom['p95_mm']:.3f} -> {ext['p95_mm']:.3f} mm p95 (gain {j['gain_pct']:.1f} %)")
    return lines


def _cause_text(cause: str, sessions: tuple[str, ...]) -> str:
    """A named cause for the report: ``a@sessions`` reads "a (differs between sessions: s1, s2)"."""
    base = cause.removesuffix(PER_SESSION)
    return cause if base == cause else f"{base} (differs between sessions: {', '.join(sessions)})"


def _noise_text(j: dict) -> str:
    return "not estimated" if j["noise_mm"] is None else f"{j['noise_mm']:.3f} mm mean tip error"


def _parameter_line(name: str, p: dict) -> str:
    """One fitted parameter of the report: value +- std (unit), its base value, and what is special."""
    if p.get("fitted") is False:
        return f"  {name} not fitted: {p['reason']}"
    std = "n/a (at its bound)" if p.get("at_bound") else ("n/a" if p["std"] is None else f"{p['std']:.3g}")
    extra = ""
    if p["unit"] == "rad":
        extra = f"  ({np.degrees(p['value']):.3f} deg +- " + (
            "n/a" if p["std"] is None else f"{np.degrees(p['std']):.3f}") + ")"
    if p.get("at_edge"):
        extra += f"  at the edge of its plausible range: {p['at_edge']}"
    return f"  {name} = {p['value']:.6g} +- {std} {p['unit']} (was {p['nominal']:.6g}){extra}"


def _tail(j: dict) -> list[str]:
    """Not explained, outliers, the sources of the plausible ranges cited above (once each), time."""
    lines = []
    if not j["explained"] and j["cause"] not in ("undetermined",):
        left = "?" if j["unexplained_mm"] is None else f"{j['unexplained_mm']:.3f}"
        lines.append(f"NOT EXPLAINED: the library does not explain the data -- {left} mm RMS of "
                     f"held-out tip error is beyond the noise")
        lines += [f"  where: {f}" for f in j["remaining"]["findings"]]
    if j["outliers"]:
        o = j["outliers"]
        fate = "excluded from the fit" if j["outliers_excluded_from_fit"] else "kept in the fit"
        lines.append(f"outliers (reported, {fate}): "
                     + ", ".join(f"row {x['row']} ({x['error_mm']:.2f} mm)" for x in o[:10])
                     + (f" and {len(o) - 10} more" if len(o) > 10 else ""))
    cited = {k for why in list(j["implausible"].values()) + list(j["at_edge"].values()) for k in why}
    texts = sorted({j["sources"][k] for k in cited if k in j["sources"]})
    if texts:
        lines.append("plausible ranges from: " + "; ".join(f"[{i + 1}] {t}" for i, t in enumerate(texts)))
    lines.append(f"time: {j['seconds']:.1f} s ({j['solves']} Cosserat solves)")
    return lines
