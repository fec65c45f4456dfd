"""Visualisation of planning results: a static PNG (matplotlib) and an offline HTML viewer."""

from ctrplan.viz.plan_plot import plot_plan
from ctrplan.viz.viewer import viewer_data, write_viewer

__all__ = ["plot_plan", "viewer_data", "write_viewer"]
