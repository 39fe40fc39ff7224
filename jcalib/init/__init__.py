"""Closed-form initialisers: they only start the joint solve, never finish it."""

from jcalib.init.homography import estimate_homographies, estimate_homography
from jcalib.init.pnp import PlanarPnPResult, PnPResult, planar_pnp, planar_pnp_views, solve_pnp
from jcalib.init.zhang import ZhangInit, zhang_init

__all__ = [
    "PlanarPnPResult",
    "PnPResult",
    "ZhangInit",
    "estimate_homographies",
    "estimate_homography",
    "planar_pnp",
    "planar_pnp_views",
    "solve_pnp",
    "zhang_init",
]
