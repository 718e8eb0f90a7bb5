"""CT noise and artefacts for synthetic tomograms (paper section 3.5), as composable seeded transforms.

Every transform takes a volume (Z, Y, X) or a single slice (H, W) of intensities
and returns a new float32 array of the same shape; axis 0 is the slice axis and
the scanner's rotation axis, which passes through the centre of every slice.
Parameters are fixed values or ``(min, max)`` ranges drawn per call, and every
random draw comes from the generator passed at call time::

    out = transform(volume, rng)              # rng: int seed, numpy Generator or None
    out, record = transform.apply(volume, rng)  # record: list of applied configs

Transforms, by config name:

========================  =============================================================
``gaussian_noise``        `GaussianNoise` (std): additive white noise
``coloured_noise``        `ColouredNoise` (pore_power, grain_power, pore_level, grain_level):
                          noise with a given spectrum in pores and grains
``speckle_noise``         `SpeckleNoise` (std): ``x * (1 + n)``
``poisson_noise``         `PoissonNoise` (photons): counting noise, variance ~ intensity
``gaussian_blur``         `GaussianBlur` (sigma): detector / focal-spot blur
``motion_blur``           `MotionBlur` (length, angle): in-slice line kernel
``ring_artefacts``        `RingArtefacts` (amplitude, n_rings, width, radii, amplitudes)
``beam_hardening``        `BeamHardening` (strength): radial cupping (signed)
``contrast_gamma``        `ContrastGamma` (contrast, gamma, pore_level, grain_level): the
                          intensity response between the two phase levels
``round_levels``          `RoundLevels` (step, offset): the grey-level grid of a scan stored as
                          integers, or as floats of regular steps
``spectrum_match``        `SpectrumMatch` (gain): a linear filter that gives a volume a source's
                          3D power spectrum about the slice normal
``ct_simulation``         `CTSimulation` (attenuation, photons, n_angles, gain_std,
                          filter_name): projection, photon noise, gain errors, FBP
``compose``               `Compose` (transforms)
========================  =============================================================

Every transform also has ``p``, the probability that it is applied at a call.
`from_config` builds a pipeline from a list of dicts such as
``[{"name": "gaussian_blur", "sigma": [0.5, 1.0]}, {"name": "gaussian_noise", "std": 0.05}]``
and ``to_dict`` / ``Compose.to_config`` write it back. `generic_postprocessing` is
a recipe scaled to the contrast alone; `noise_to_add` matches a source scan's noise level and
`calibrate` fits the PSF and the noise spectrum to its edges and noise power spectrum (measured on
its noise alone), keeping only the steps that its guard (``guard``) finds make the pack more like it.
"""

from ._base import Compose, Transform, available_transforms, from_config
from ._param import Param
from .blur import GaussianBlur, MotionBlur, line_kernel
from .calibrate import Calibration, calibrate, noise_to_add
from .calibration_region import calibration_halo, measured_slices
from .coloured_noise import ColouredNoise
from .ct import CTSimulation
from .intensity import ContrastGamma, RoundLevels
from .noise import GaussianNoise, PoissonNoise, SpeckleNoise
from .presets import generic_postprocessing
from .radial import BeamHardening, RingArtefacts
from .spectrum_match import SpectrumMatch

__all__ = [
    "BeamHardening",
    "CTSimulation",
    "Calibration",
    "ColouredNoise",
    "Compose",
    "ContrastGamma",
    "RoundLevels",
    "GaussianBlur",
    "GaussianNoise",
    "MotionBlur",
    "Param",
    "PoissonNoise",
    "RingArtefacts",
    "SpeckleNoise",
    "SpectrumMatch",
    "Transform",
    "available_transforms",
    "calibrate",
    "calibration_halo",
    "from_config",
    "generic_postprocessing",
    "line_kernel",
    "measured_slices",
    "noise_to_add",
]
