"""Figures and pages: every PNG and HTML ctrplan writes, rendered from the results of the layers
below in one style (`ctrplan.viz.style`); commands call them, nothing below renders.

Plans (plan.png, the offline 3-D viewer plan.html, path.json and trajectory.csv), stability sweeps,
the PINN's figures, diagnosis residuals, benchmark plots and the design study's figures and report.
"""

from ctrplan.viz.plan_plot import plot_plan
from ctrplan.viz.viewer import viewer_data, write_viewer

__all__ = ["plot_plan", "viewer_data", "write_viewer"]
