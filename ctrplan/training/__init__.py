"""Training of the PINN surrogate: physics residuals, samplers, losses, recipes and the trainer."""
