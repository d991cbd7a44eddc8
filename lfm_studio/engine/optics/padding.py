"""Centred zero padding and cropping of fields: the one place where both happen.

Convention (see :class:`Grid`): the optical axis of an axis with ``N`` samples is
index ``N // 2``. Padding ``N -> M`` puts ``M // 2 - N // 2`` zeros before the data
and the rest after, so the axis stays at index ``M // 2``; cropping ``M -> N``
keeps samples ``M // 2 - N // 2 ... M // 2 - N // 2 + N - 1``. Hence
``crop(pad(x, M), N) == x`` for every ``N <= M``, odd or even.

Padded sizes chosen from a factor are rounded up to the next 2-3-5-7-smooth
integer (fast FFT sizes; powers of two stay as they are).
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.optics.field import Field

Shape = tuple[int, int]


def _next_fast_size(n: int) -> int:
    """Smallest integer ``>= n`` whose prime factors are all in (2, 3, 5, 7)."""
    m = max(int(n), 1)
    while True:
        k = m
        for p in (2, 3, 5, 7):
            while k % p == 0:
                k //= p
        if k == 1:
            return m
        m += 1


def padded_shape(shape: Shape, factor: float) -> Shape:
    """Shape after padding ``shape = (ny, nx)`` by ``factor >= 1`` (fast FFT sizes).

    ``factor = 1`` keeps the shape; otherwise each axis becomes the next fast FFT
    size ``>= ceil(n * factor)``.
    """
    factor = float(factor)
    if not (math.isfinite(factor) and factor >= 1.0):
        raise ValueError(
            f"padding must be a finite factor >= 1 (1 = no padding); got {factor!r}. "
            "Fix: use padding=2.0 (the default) to avoid wrap-around, or 1.0 for periodic fields."
        )
    if factor == 1.0:
        return (int(shape[0]), int(shape[1]))
    return tuple(_next_fast_size(math.ceil(n * factor - 1e-9)) for n in shape)  # type: ignore[return-value]


def _offsets(inner: int, outer: int) -> int:
    return outer // 2 - inner // 2


def _require_shape(shape: Shape, *, at_least: Shape | None = None, at_most: Shape | None = None) -> Shape:
    ny, nx = (int(shape[0]), int(shape[1]))
    if ny < 1 or nx < 1 or (ny, nx) != tuple(shape):
        raise ValueError(f"shape must be a pair of positive integers (ny, nx); got {shape!r}.")
    if at_least is not None and (ny < at_least[0] or nx < at_least[1]):
        raise ValueError(
            f"padded shape {shape!r} is smaller than the data {at_least!r}. Fix: use crop_field."
        )
    if at_most is not None and (ny > at_most[0] or nx > at_most[1]):
        raise ValueError(f"cropped shape {shape!r} is larger than the data {at_most!r}. Fix: use pad_field.")
    return (ny, nx)


def pad_to(data: torch.Tensor, shape: Shape) -> torch.Tensor:
    """Zero-pad the last two dims of ``data`` to ``shape``, centred (returns ``data`` if equal)."""
    ny, nx = data.shape[-2:]
    my, mx = _require_shape(shape, at_least=(ny, nx))
    if (my, mx) == (ny, nx):
        return data
    top, left = _offsets(ny, my), _offsets(nx, mx)
    return torch.nn.functional.pad(data, (left, mx - nx - left, top, my - ny - top))


def crop_to(data: torch.Tensor, shape: Shape) -> torch.Tensor:
    """Centred crop of the last two dims of ``data`` to ``shape`` (a copy; ``data`` if equal)."""
    my, mx = data.shape[-2:]
    ny, nx = _require_shape(shape, at_most=(my, mx))
    if (my, mx) == (ny, nx):
        return data
    top, left = _offsets(ny, my), _offsets(nx, mx)
    return data[..., top : top + ny, left : left + nx].clone()


def crop_reversed(data: torch.Tensor, shape: Shape) -> torch.Tensor:
    """Centred crop of the index-reversed array ``y[n] = data[(-n) mod M]`` (a copy).

    The propagators finish an inverse DFT as a forward DFT,
    ``ifft(X)[n] = fft(X)[(-n) mod M] / M``, with the ``1/M`` folded into their
    transfer function (no extra pass over the padded array); this crop undoes the
    index reversal and the padding in one copy of the small output.
    """
    my, mx = data.shape[-2:]
    ny, nx = _require_shape(shape, at_most=(my, mx))
    for dim, inner, outer in ((-2, ny, my), (-1, nx, mx)):
        # wanted, before the final flip: indices (-(s + i)) mod outer for i = inner-1 .. 0
        s = _offsets(inner, outer)
        if s >= 1:  # outer - s - inner + 1 ... outer - s: one slice
            data = data.narrow(dim, outer - s - inner + 1, inner)
        else:  # s == 0: outer - inner + 1 ... outer - 1, then 0
            data = data.roll(-1, dim).narrow(dim, outer - inner, inner)
    return data.flip((-2, -1))


def pad_field(field: Field, factor: float | None = None, *, shape: Shape | None = None) -> Field:
    """Zero-pad ``field`` (centred) by ``factor`` or to ``shape``; spacing unchanged.

    Parameters
    ----------
    field : Field, data shape ``(..., ny, nx)``.
    factor : float >= 1, optional
        Pad each axis to the next fast FFT size ``>= ceil(n * factor)``.
    shape : (my, mx), optional
        Exact padded shape (``my >= ny``, ``mx >= nx``). Give exactly one of the two.

    Returns
    -------
    Field on ``field.grid.with_shape(new_shape)``; the optical axis stays at index ``M // 2``.
    """
    if factor is not None and shape is None:
        new_shape = padded_shape(field.grid.shape, factor)
    elif shape is not None and factor is None:
        new_shape = shape
    else:
        raise ValueError("pad_field needs exactly one of factor or shape; got both or neither.")
    data = pad_to(field.data, new_shape)
    return field.with_data(data, grid=field.grid.with_shape((data.shape[-2], data.shape[-1])))


def crop_field(field: Field, shape: Shape) -> Field:
    """Centred crop of ``field`` to ``shape = (ny, nx)``; spacing unchanged (inverse of :func:`pad_field`)."""
    data = crop_to(field.data, shape)
    return field.with_data(data, grid=field.grid.with_shape((data.shape[-2], data.shape[-1])))
