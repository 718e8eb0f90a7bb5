"""The scanner's blur, fitted to the mean edge profile: the edge-spread function (ESF) of a scan.

A scanner images a grain-pore boundary as a step blurred by its point-spread
function (PSF). For a Gaussian PSF of ``sigma`` voxels the mean intensity at
signed distance ``x`` (voxels, positive in grains, `synthpack.measure.edges`) from
the label boundary is

    I(x) = pore + contrast * Phi((x - shift) / sigma)

with ``Phi`` the standard normal distribution function and ``contrast = grain -
pore`` (either sign). ``shift`` is where the intensity edge lies relative to the
label boundary (its half-height; > 0: inside the grains, as when the labels are a
little too large), ``sigma`` the total width: the scanner's PSF and the
partial-volume spread of voxels whose centres sit anywhere between the boundary
and the next voxel. `fit_edge_spread` fits all four numbers by least squares,
each profile point weighted by its number of voxels, so the fit is the
least-squares fit over every voxel within `~synthpack.measure.edges.REACH` of a
boundary. Levels are fitted rather than taken from the interiors, so a scan whose
grains are too thin to have an interior still gets its edge.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import optimize, special

from .._shared.text import sig
from ..errors import SynthpackInputError
from .edges import EdgeProfile

logger = logging.getLogger(__name__)

__all__ = ["EdgeSpread", "fit_edge_spread"]

#: The fitted sigma is kept within these bounds, voxels.
_SIGMA_BOUNDS = (0.05, 4.0)


@dataclass(frozen=True)
class EdgeSpread:
    """A fitted edge-spread function ``pore + (grain - pore) Phi((x - shift) / sigma)``.

    Attributes
    ----------
    shift : float
        Position of the half-height relative to the label boundary, voxels (> 0: inside the grains).
    sigma : float
        Gaussian width of the edge, voxels.
    pore, grain : float
        Fitted levels far from the edge on either side, intensity units.
    """

    shift: float
    sigma: float
    pore: float
    grain: float

    def __call__(self, distance: np.ndarray) -> np.ndarray:
        """The model at signed distances `distance` (voxels), float64, same shape."""
        step = special.ndtr((np.asarray(distance, dtype=np.float64) - self.shift) / self.sigma)
        return self.pore + (self.grain - self.pore) * step


def fit_edge_spread(profile: EdgeProfile) -> EdgeSpread:
    """Fit the Gaussian edge-spread function to an edge profile (see the module docstring).

    Parameters
    ----------
    profile : EdgeProfile
        From `~synthpack.measure.edges.edge_profile`; each point weighs as many voxels as it averages.

    Returns
    -------
    EdgeSpread

    Raises
    ------
    SynthpackInputError
        If the profile has fewer than 5 points, or no step (grain level equal to pore level).

    Examples
    --------
    >>> from synthpack.measure.edges import EdgeProfile
    >>> x = np.linspace(-4, 4, 33)
    >>> truth = EdgeSpread(shift=0.3, sigma=0.8, pore=0.2, grain=0.7)
    >>> fit = fit_edge_spread(EdgeProfile(x, truth(x), 0.2, 0.7, np.ones(33, dtype=np.int64)))
    >>> round(fit.shift, 3), round(fit.sigma, 3)
    (0.3, 0.8)
    """
    if len(profile.distance) < 5:
        raise SynthpackInputError(f"the edge profile has {len(profile.distance)} points; fitting its blur needs 5")
    if profile.grain_level == profile.pore_level:
        raise SynthpackInputError("the edge profile has no step (grains as bright as pores): no blur to fit")
    x = profile.distance
    weight = np.sqrt(profile.count.astype(np.float64))
    scale = abs(profile.grain_level - profile.pore_level)

    def residual(p: np.ndarray) -> np.ndarray:
        shift, sigma, pore, grain = p
        model = pore + (grain - pore) * special.ndtr((x - shift) / sigma)
        return weight * (model - profile.intensity) / scale

    start = np.array([0.0, 1.0, profile.pore_level, profile.grain_level])
    lower = [x.min(), _SIGMA_BOUNDS[0], -np.inf, -np.inf]
    upper = [x.max(), _SIGMA_BOUNDS[1], np.inf, np.inf]
    solution = optimize.least_squares(residual, start, bounds=(lower, upper), x_scale=[1.0, 1.0, scale, scale])
    shift, sigma, pore, grain = (float(v) for v in solution.x)
    logger.debug("edge spread: shift %s voxels, sigma %s voxels (pores %s, grains %s)", sig(shift), sig(sigma),
                 sig(pore), sig(grain))
    return EdgeSpread(shift, sigma, pore, grain)
