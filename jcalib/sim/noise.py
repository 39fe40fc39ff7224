"""Image sensor model: mean collected electrons -> noisy, quantised digital numbers (DN).

The model (EMVA 1288 style, linear sensor): photo-electrons are Poisson distributed (shot noise), the
pixel saturates at its full-well capacity, the readout adds Gaussian read noise (electrons), the
analogue-to-digital converter multiplies by the system gain (DN per electron), adds the black level
and rounds to an integer clipped to ``[0, 2**bit_depth - 1]``. Dark current and fixed-pattern noise
(PRNU/DSNU) are not modelled.
"""

from __future__ import annotations

import numpy as np

from jcalib.errors import BadInputError

BIT_DEPTHS = (8, 10, 12, 14, 16)


def max_dn(bit_depth: int) -> int:
    """Largest digital number of a ``bit_depth``-bit sensor output."""
    return (1 << int(bit_depth)) - 1


def output_dtype(bit_depth: int) -> type:
    """``np.uint8`` for 8-bit output, ``np.uint16`` for 10..16-bit (values kept LSB-aligned)."""
    return np.uint8 if bit_depth == 8 else np.uint16


def default_gain_dn_per_e(bit_depth: int, full_well_e: float) -> float:
    """The gain that maps a full well to the top of the ADC range, DN per electron."""
    return max_dn(bit_depth) / float(full_well_e)


def check_sensor_settings(
    bit_depth: int, full_well_e: float, read_noise_e: float, gain_dn_per_e: float | None, black_level_dn: float
) -> None:
    """Raise :class:`BadInputError` naming the first invalid sensor setting."""
    if bit_depth not in BIT_DEPTHS:
        raise BadInputError(f"bit_depth: got {bit_depth!r}, expected one of {BIT_DEPTHS}")
    if not (np.isfinite(full_well_e) and full_well_e > 0):
        raise BadInputError(f"full_well_e: got {full_well_e!r}, expected a positive number of electrons")
    if not (np.isfinite(read_noise_e) and read_noise_e >= 0):
        raise BadInputError(f"read_noise_e: got {read_noise_e!r}, expected a number of electrons >= 0")
    if gain_dn_per_e is not None and not (np.isfinite(gain_dn_per_e) and gain_dn_per_e > 0):
        raise BadInputError(f"gain_dn_per_e: got {gain_dn_per_e!r}, expected a positive DN/electron or None")
    if not (np.isfinite(black_level_dn) and 0 <= black_level_dn <= max_dn(bit_depth)):
        raise BadInputError(
            f"black_level_dn: got {black_level_dn!r}, expected a value in [0, {max_dn(bit_depth)}] DN"
        )


_POISSON_EXACT_BELOW_E = 1000.0


def _shot_noise(mean: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Poisson photo-electron counts of the given means. Means of at least 1000 e- use the normal
    approximation N(mean, mean) rounded to whole electrons (skewness 1/sqrt(mean) <= 0.03: the two
    distributions are indistinguishable for images, and it is several times faster)."""
    out = np.rint(mean + np.sqrt(mean) * rng.standard_normal(mean.shape))
    small = mean < _POISSON_EXACT_BELOW_E
    if np.any(small):
        out[small] = rng.poisson(mean[small])
    return np.maximum(out, 0.0)


def sensor_response(
    electrons: np.ndarray,
    rng: np.random.Generator,
    *,
    bit_depth: int = 8,
    full_well_e: float = 10000.0,
    read_noise_e: float = 3.0,
    gain_dn_per_e: float | None = None,
    black_level_dn: float = 0.0,
    shot_noise: bool = True,
    approximate: bool = False,
) -> np.ndarray:
    """Turn mean collected electrons into a noisy integer image.

    Args:
        electrons: (H, W) mean photo-electrons per pixel (>= 0) for the exposure.
        rng: random generator for shot and read noise (only consumed when the noise is on).
        bit_depth: ADC resolution, one of 8, 10, 12, 14, 16.
        full_well_e: saturation capacity, electrons.
        read_noise_e: standard deviation of the Gaussian read noise, electrons (0 = off).
        gain_dn_per_e: system gain, DN per electron; None maps a full well to ``2**bit_depth - 1``.
        black_level_dn: offset added to every pixel before rounding, DN.
        shot_noise: draw Poisson photo-electrons (True; normal approximation from 1000 e-) or use the mean (False).
        approximate: draw shot and read noise in one float32 normal draw, N(mean, mean + read²), clipped to
            [0, full well] (fast; for live simulated cameras). False: the exact model above.

    Returns:
        (H, W) ``uint8`` (8-bit) or ``uint16`` image of digital numbers.
    """
    check_sensor_settings(bit_depth, full_well_e, read_noise_e, gain_dn_per_e, black_level_dn)
    gain = default_gain_dn_per_e(bit_depth, full_well_e) if gain_dn_per_e is None else float(gain_dn_per_e)
    if approximate:
        mean32 = np.clip(np.asarray(electrons, dtype=np.float32), 0.0, None)
        var = (mean32 if shot_noise else np.zeros_like(mean32)) + np.float32(read_noise_e) ** 2
        sig = np.sqrt(var, out=var)
        sig *= rng.standard_normal(mean32.shape, dtype=np.float32)
        sig += mean32
        np.clip(sig, 0.0, np.float32(full_well_e), out=sig)
        sig *= np.float32(gain)
        sig += np.float32(black_level_dn)
        np.rint(sig, out=sig)
        return np.clip(sig, 0, max_dn(bit_depth), out=sig).astype(output_dtype(bit_depth))
    mean = np.clip(np.asarray(electrons, dtype=np.float64), 0.0, None)
    signal = _shot_noise(mean, rng) if shot_noise else mean
    signal = np.minimum(signal, float(full_well_e))
    if read_noise_e > 0:
        signal = signal + rng.normal(0.0, float(read_noise_e), size=signal.shape)
    dn = np.rint(signal * gain + float(black_level_dn))
    return np.clip(dn, 0, max_dn(bit_depth)).astype(output_dtype(bit_depth))
