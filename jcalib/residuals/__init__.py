"""Residual building blocks shared by problems: robust losses and priors."""

from jcalib.residuals.losses import CauchyLoss, HuberLoss, Loss, TrivialLoss
from jcalib.residuals.priors import gaussian_prior_jacobian, gaussian_prior_residual

__all__ = ["CauchyLoss", "HuberLoss", "Loss", "TrivialLoss", "gaussian_prior_jacobian", "gaussian_prior_residual"]
