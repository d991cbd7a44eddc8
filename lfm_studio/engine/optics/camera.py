"""The camera: irradiance -> power per sensor pixel -> photo-electrons -> digital counts.

Staged like a real sensor (each stage a pure function, each noise source optional):

1. :func:`intensity` ``|U|^2`` of a field (irradiance, W/m^2 for a field in sqrt(W)/m);
2. :func:`integrate_pixels`: exact area integral over each sensor pixel (power, W);
3. :func:`expected_electrons`: scale to photons (``photons`` in the whole image or
   ``photons_per_unit`` of power) times the quantum efficiency: the noise-free image;
4. :func:`sample_electrons`: Poisson shot noise, full-well clipping, Gaussian read noise;
5. :func:`digitize`: gain (ADU/e-) + baseline, rounding to integers, clipping to
   ``[0, 2^bit_depth - 1]``.

:func:`simulate_sensor` chains 3-5 and :func:`capture` runs 1-5 on a field. Stages 1-3 and digitize without rounding are
differentiable; sampling and rounding are not (their gradient is zero or absent).
Randomness comes only from an explicit ``torch.Generator`` or integer seed: same
seed, same image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lfm_studio.engine.errors import require_finite, require_finite_tensor, require_positive
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid


class SaturationWarning(UserWarning):
    """Simulated pixels exceed the camera's full well or ADC range: their counts are clipped."""


@dataclass(frozen=True)
class Camera:
    """A pixelated sensor (engine-side, SI units).

    Attributes
    ----------
    pixel_pitch : float
        Pixel pitch in metres (square pixels, 100% fill factor).
    shape : (ny, nx) or None
        Sensor size in pixels; None = just large enough to cover the simulated field.
    quantum_efficiency : float
        Photo-electrons per photon, in ``(0, 1]``.
    read_noise : float
        Gaussian read noise, electrons rms (>= 0).
    gain : float
        Conversion gain, ADU per electron (> 0).
    bit_depth : int
        ADC bits, 1..32; counts saturate at ``2^bit_depth - 1``.
    baseline : float
        Offset added to every pixel, ADU (>= 0, below the saturation value).
    full_well : float or None
        Electrons a pixel holds before it saturates (None = unlimited).
    """

    pixel_pitch: float
    shape: tuple[int, int] | None = None
    quantum_efficiency: float = 1.0
    read_noise: float = 0.0
    gain: float = 1.0
    bit_depth: int = 16
    baseline: float = 0.0
    full_well: float | None = None

    def __post_init__(self) -> None:
        require_positive("pixel_pitch", self.pixel_pitch, "m", "give the sensor pixel pitch, e.g. 6.5 * um.")
        if self.shape is not None:
            if len(self.shape) != 2 or any(int(s) != s or s < 1 for s in self.shape):
                raise ValueError(f"shape must be (ny, nx) positive integers or None; got {self.shape!r}.")
            object.__setattr__(self, "shape", (int(self.shape[0]), int(self.shape[1])))
        qe = float(self.quantum_efficiency)
        if not 0.0 < qe <= 1.0:
            raise ValueError(
                f"quantum_efficiency must be in (0, 1] electrons/photon; got {qe!r}. Fix: e.g. 0.8."
            )
        require_finite("read_noise", self.read_noise, "e- rms")
        if self.read_noise < 0:
            raise ValueError(
                f"read_noise must be >= 0 e- rms; got {self.read_noise!r} e- rms. Fix: e.g. 1.5."
            )
        require_positive("gain", self.gain, "ADU/e-", "e.g. 0.5 ADU per electron.")
        bits = self.bit_depth
        if isinstance(bits, bool) or not isinstance(bits, int) or not 1 <= bits <= 32:
            raise ValueError(
                f"bit_depth must be an integer from 1 to 32 bits; got {bits!r}. Fix: e.g. 12 or 16."
            )
        require_finite("baseline", self.baseline, "ADU")
        if not 0 <= self.baseline < self.max_count:
            raise ValueError(
                f"baseline must be in [0, {self.max_count}) ADU for a {bits}-bit ADC; "
                f"got {self.baseline!r} ADU. Fix: use a smaller offset, e.g. 100 ADU."
            )
        if self.full_well is not None:
            require_positive(
                "full_well", self.full_well, "e-", "e.g. 30000 electrons, or None for unlimited."
            )

    @property
    def max_count(self) -> int:
        """Saturation value ``2^bit_depth - 1`` in ADU."""
        return 2**self.bit_depth - 1

    @property
    def saturation_electrons(self) -> float:
        """Electrons at which a pixel's counts stop growing: the full well or the ADC's top
        (``(max_count - baseline) / gain``), whichever comes first."""
        top = (self.max_count - self.baseline) / self.gain
        return top if self.full_well is None else min(top, float(self.full_well))


def intensity(field: Field) -> torch.Tensor:
    """``|U|^2`` of ``field``: real irradiance, shape ``field.data.shape`` (W/m^2 for sqrt(W)/m)."""
    return field.intensity()


def _pair(value: float | tuple[float, float], name: str) -> tuple[float, float]:
    pair = tuple(value) if isinstance(value, (tuple, list)) else (value, value)
    if len(pair) != 2:
        raise ValueError(f"{name} must be a number or a (y, x) pair; got {value!r}.")
    return float(pair[0]), float(pair[1])


def _covering_count(n: int, d: float, p: float, offset: float) -> int:
    """Fewest centred sensor pixels (pitch ``p``) covering ``n`` samples of spacing ``d``."""
    lo, hi = (-(n // 2) - 0.5) * d, (n - 1 - n // 2 + 0.5) * d
    count = max(1, math.ceil(n * d / p - 1e-9))
    while (-(count // 2) - 0.5) * p + offset > lo + 1e-9 * p or (
        count - 1 - count // 2 + 0.5
    ) * p + offset < hi - 1e-9 * p:
        count += 1
    return count


def _overlap(n: int, d: float, count: int, p: float, offset: float, device, dtype) -> torch.Tensor:
    """``W[j, i]`` = length (m) of sensor pixel ``j`` overlapping sample cell ``i``."""
    cells = (torch.arange(n, device=device, dtype=torch.float64) - n // 2) * d
    pixels = (torch.arange(count, device=device, dtype=torch.float64) - count // 2) * p + offset
    lo = torch.maximum(pixels[:, None] - p / 2, cells[None, :] - d / 2)
    hi = torch.minimum(pixels[:, None] + p / 2, cells[None, :] + d / 2)
    return (hi - lo).clamp(min=0.0).to(dtype)


def integrate_pixels(
    irradiance: torch.Tensor,
    grid: Grid,
    pixel_pitch: float | tuple[float, float],
    *,
    shape: tuple[int, int] | None = None,
    offset: tuple[float, float] = (0.0, 0.0),
) -> torch.Tensor:
    """Power collected by each sensor pixel: the exact integral of the irradiance over it.

    The irradiance is taken as constant over each grid cell (``dy x dx`` around each
    sample); pixel ``(j, i)`` of the sensor is centred at
    ``((j - ny//2) py + offset_y, (i - nx//2) px + offset_x)`` (the :class:`Grid`
    convention). The result is ``W_y @ I @ W_x^T`` with ``W[j, i]`` the overlap length
    of pixel ``j`` and cell ``i``: any pitch ratio (non-integer, or pitch below the
    sample spacing), linear and differentiable in ``irradiance``, and energy-conserving
    when the sensor covers the field.

    Parameters
    ----------
    irradiance : real tensor ``(..., ny, nx)`` on ``grid`` (W/m^2).
    grid : Grid of the irradiance samples (metres).
    pixel_pitch : float or (py, px), metres.
    shape : sensor size (pixels); None = the fewest pixels covering the whole grid.
    offset : (y, x) shift of the sensor centre from the optical axis, metres.

    Returns
    -------
    Tensor ``(..., sensor_ny, sensor_nx)`` of power per pixel (W), dtype of ``irradiance``.
    """
    if not isinstance(irradiance, torch.Tensor) or irradiance.is_complex():
        raise TypeError("irradiance must be a real torch.Tensor; use intensity(field) for a complex field.")
    if tuple(irradiance.shape[-2:]) != grid.shape:
        raise ValueError(
            f"irradiance shape {tuple(irradiance.shape)} does not end in the grid shape {grid.shape}."
        )
    py, px = _pair(pixel_pitch, "pixel_pitch")
    require_positive("pixel_pitch", py, "m", "give the sensor pixel pitch in metres, e.g. 6.5 * um.")
    require_positive("pixel_pitch", px, "m", "give the sensor pixel pitch in metres, e.g. 6.5 * um.")
    oy, ox = _pair(offset, "offset")
    require_finite("offset", oy, "m")
    require_finite("offset", ox, "m")
    if shape is None:
        shape = (_covering_count(grid.ny, grid.dy, py, oy), _covering_count(grid.nx, grid.dx, px, ox))
    elif len(shape) != 2 or any(int(s) != s or s < 1 for s in shape):
        raise ValueError(f"shape must be (ny, nx) positive integers or None; got {shape!r}.")
    kwargs = {"device": irradiance.device, "dtype": irradiance.dtype}
    w_y = _overlap(grid.ny, grid.dy, int(shape[0]), py, oy, **kwargs)
    w_x = _overlap(grid.nx, grid.dx, int(shape[1]), px, ox, **kwargs)
    return w_y @ irradiance @ w_x.T


def expected_electrons(
    power_image: torch.Tensor,
    camera: Camera,
    *,
    photons: float | None = None,
    photons_per_unit: float | None = None,
) -> torch.Tensor:
    """Noise-free photo-electrons per pixel: ``QE * photons_per_unit * power``.

    Give ``photons`` (expected photons in each image, i.e. summed over the last two
    dims) or ``photons_per_unit`` (photons per unit of ``power_image``); neither means
    ``power_image`` already counts photons. Negative values in ``power_image`` (FFT
    round-off) are clipped to 0.
    """
    if photons is not None and photons_per_unit is not None:
        raise ValueError("give photons or photons_per_unit, not both.")
    require_finite_tensor("power_image", power_image.detach())
    rate = power_image.clamp(min=0.0)
    if photons is not None:
        require_finite("photons", photons, "photons")
        if photons < 0:
            raise ValueError(f"photons must be >= 0 (expected photons per image); got {photons!r}.")
        total = rate.sum(dim=(-2, -1), keepdim=True)
        rate = rate * (photons / torch.where(total > 0, total, torch.ones_like(total)))
    elif photons_per_unit is not None:
        require_finite("photons_per_unit", photons_per_unit, "photons per unit power")
        if photons_per_unit < 0:
            raise ValueError(f"photons_per_unit must be >= 0; got {photons_per_unit!r}.")
        rate = rate * photons_per_unit
    return rate * camera.quantum_efficiency


def saturation_note(power_image: torch.Tensor, camera: Camera, *, photons: float) -> str | None:
    """``None`` when no pixel of ``power_image`` scaled to ``photons`` (as in
    :func:`expected_electrons`) expects more electrons than :attr:`Camera.saturation_electrons`;
    else a message saying how many pixels clip, at what, and the largest ``photons`` that keeps
    the brightest pixel below it."""
    rate = power_image.detach().clamp(min=0.0).double()
    total = float(rate.sum())
    if not total > 0:
        return None
    per_unit = photons * camera.quantum_efficiency / total  # electrons per unit of power_image
    limit = camera.saturation_electrons
    clipped = int((rate * per_unit > limit).sum())
    if clipped == 0:
        return None
    top = (camera.max_count - camera.baseline) / camera.gain
    what = (
        f"the full well, {camera.full_well:g} e-"
        if camera.full_well is not None and camera.full_well <= top
        else f"the {camera.bit_depth}-bit ADC's top, {camera.max_count} ADU"
    )
    safe = photons * limit / (float(rate.max()) * per_unit)
    step = 10.0 ** (math.floor(math.log10(safe)) - 2)
    return (
        f"photons={photons:g} saturates the camera: {clipped} of {rate.numel()} pixels expect more than "
        f"{limit:.6g} e- ({what}), so their counts are clipped and the image holds fewer photons than asked. "
        f"Fix: photons <= {math.floor(safe / step) * step:.3g} keeps the brightest pixel below saturation "
        "(or use a camera with a larger full well or more ADC bits)."
    )


def _generator(generator: torch.Generator | int | None, device: torch.device) -> torch.Generator:
    if isinstance(generator, torch.Generator):
        return generator
    if isinstance(generator, int) and not isinstance(generator, bool):
        return torch.Generator(device=device).manual_seed(generator)
    raise ValueError(
        f"generator must be a torch.Generator or an integer seed when noise is on; got {generator!r}. "
        "Fix: pass generator=torch.Generator().manual_seed(0) or generator=0 (same seed, same image)."
    )


def sample_electrons(
    electrons: torch.Tensor,
    camera: Camera,
    *,
    generator: torch.Generator | int | None = None,
    shot_noise: bool = True,
    read_noise: bool = True,
) -> torch.Tensor:
    """Electrons read out: Poisson(expected), clipped at the full well, plus read noise (e- rms)."""
    out = electrons
    noisy = shot_noise or (read_noise and camera.read_noise > 0)
    gen = _generator(generator, electrons.device) if noisy else None
    if shot_noise:
        out = torch.poisson(electrons.detach().clamp(min=0.0), generator=gen)
    if camera.full_well is not None:
        out = out.clamp(max=camera.full_well)
    if read_noise and camera.read_noise > 0:
        noise = torch.randn(out.shape, generator=gen, device=out.device, dtype=out.dtype)
        out = out + camera.read_noise * noise
    return out


def digitize(
    electrons: torch.Tensor, camera: Camera, *, quantize: bool = True, saturate: bool = True
) -> torch.Tensor:
    """ADU = ``gain * electrons + baseline``, rounded to integers, clipped to ``[0, 2^bits - 1]``."""
    counts = electrons * camera.gain + camera.baseline
    if quantize:
        counts = torch.round(counts)
    if saturate:
        counts = counts.clamp(min=0.0, max=float(camera.max_count))
    return counts


def simulate_sensor(
    power_image: torch.Tensor,
    camera: Camera,
    *,
    photons: float | None = None,
    photons_per_unit: float | None = None,
    generator: torch.Generator | int | None = None,
    shot_noise: bool = True,
    read_noise: bool = True,
    quantize: bool = True,
    saturate: bool = True,
) -> torch.Tensor:
    """Digital counts (ADU, float tensor ``power_image.shape``) for a power image per pixel.

    Chains :func:`expected_electrons`, :func:`sample_electrons` and :func:`digitize`
    (see those for the parameters). With every noise source and the quantisation
    off it is differentiable: ``gain * QE * photons_per_unit * power + baseline``.
    """
    electrons = expected_electrons(power_image, camera, photons=photons, photons_per_unit=photons_per_unit)
    electrons = sample_electrons(
        electrons, camera, generator=generator, shot_noise=shot_noise, read_noise=read_noise
    )
    return digitize(electrons, camera, quantize=quantize, saturate=saturate)


def capture(
    field: Field,
    camera: Camera,
    *,
    offset: tuple[float, float] = (0.0, 0.0),
    **sensor_options,
) -> torch.Tensor:
    """Field on the sensor plane -> digital counts: :func:`intensity`, :func:`integrate_pixels`
    at ``camera.pixel_pitch`` over ``camera.shape`` (None: covering the field), then
    :func:`simulate_sensor` with ``sensor_options`` (``photons``, ``generator``, ...)."""
    power = integrate_pixels(
        intensity(field), field.grid, camera.pixel_pitch, shape=camera.shape, offset=offset
    )
    return simulate_sensor(power, camera, **sensor_options)
