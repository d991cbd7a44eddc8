"""Hypothesis strategies for random *valid* Fourier-LFM designs, small enough to simulate fast.

Construction (lengths in micrometres unless named otherwise), so that every design passes
``Design`` validation without a single ``DesignWarning``:

1. emission ``lambda`` 400-700 nm; immersion air / water / oil; ``NA = n u`` (``u`` in
   [0.1, 0.92], capped at 1.4) on a 10x-100x objective with a 200 mm tube lens;
2. camera: 64-256 px per side, 2-8 um pixels, half-width ``W``;
3. lenslets: 1 (on axis), 3 (a row) or 7 (hexagonal ring) at pitch ``P = q W``
   (``q`` in [0.25, 0.6]), aperture ``D = fill * P`` (circles or squares that never
   overlap), so centres lie on the sensor and the relay is chosen to put every lenslet
   inside the pupil image: ``R_pupil = (P + rim) (1 + slack)``, ``f_relay = M R / NA``;
4. field stop at the native image plane such that each sub-image has radius ``0.45 P``
   (a single lenslet: ``0.45 W``): sub-images neither overlap nor cross the sensor edge;
5. lenslet focal length ``f = (2 D p / lambda) * g`` (``g`` in [1.01, 3]) so the pixels sample the
   sub-images at Nyquist, clamped to [0.5, 50] mm (the design's Nyquist check then still
   holds); the camera sits at the lenslets' focal plane;
6. 1-3 depths, evenly spaced by 0.5-4 depths of field ``lambda n / NA^2``, centred on focus.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hypothesis import strategies as st

from lfm_studio.engine.design import (
    AccuracySpec,
    CameraSpec,
    DepthSpec,
    Design,
    LensletSpec,
    MLASpec,
    ObjectiveSpec,
    RelayLensSpec,
)

IMMERSION = (1.0, 1.333, 1.515)
MAGNIFICATIONS = (10.0, 20.0, 40.0, 60.0, 100.0)
LAYOUTS = ("single", "row", "hex")
MIN_FOCAL_MM, MAX_FOCAL_MM = 0.5, 50.0


@dataclass(frozen=True)
class DesignParameters:
    """The drawn parameters of one design (kept for messages and references)."""

    wavelength_nm: float
    immersion_index: float
    numerical_aperture: float
    magnification: float
    pixels: int
    pixel_um: float
    layout: str
    pitch_fraction: float
    fill: float
    shape: str
    slack: float
    focal_factor: float
    depth_count: int
    depth_step_dofs: float
    accuracy: str


def _centres(layout: str, pitch_um: float) -> list[tuple[float, float]]:
    if layout == "single":
        return [(0.0, 0.0)]
    if layout == "row":
        return [(-pitch_um, 0.0), (0.0, 0.0), (pitch_um, 0.0)]
    ring = [(pitch_um * math.cos(math.pi / 3 * k), pitch_um * math.sin(math.pi / 3 * k)) for k in range(6)]
    return [(0.0, 0.0), *[(round(x, 6), round(y, 6)) for x, y in ring]]


def build_design(p: DesignParameters) -> Design:
    """The valid design described by ``p`` (see the module docstring)."""
    na = min(1.4, p.numerical_aperture)
    half_width_um = p.pixels * p.pixel_um / 2.0
    pitch_um = p.pitch_fraction * half_width_um
    diameter_um = p.fill * pitch_um
    if p.shape == "square":
        diameter_um = min(diameter_um, pitch_um * math.sqrt(3.0) / 2.0)  # hex neighbours at 60 degrees
    rim_um = diameter_um / 2.0 * (math.sqrt(2.0) if p.shape == "square" else 1.0)
    centres = _centres(p.layout, pitch_um)
    reach_um = max(math.hypot(*c) for c in centres) + rim_um
    pupil_radius_um = reach_um * (1.0 + p.slack)
    relay_mm = p.magnification * pupil_radius_um / na * 1e-3
    wavelength_um = p.wavelength_nm * 1e-3
    nyquist_focal_mm = 2.0 * diameter_um * p.pixel_um / wavelength_um * 1e-3
    focal_mm = min(MAX_FOCAL_MM, max(MIN_FOCAL_MM, nyquist_focal_mm * p.focal_factor))
    if focal_mm < nyquist_focal_mm * 1.01:  # clamped near Nyquist: shrink the lenslets instead
        diameter_um *= focal_mm / (nyquist_focal_mm * 1.01)
    sub_image_um = 0.45 * (pitch_um if p.layout != "single" else half_width_um)
    stop_mm = 2.0 * sub_image_um * relay_mm / focal_mm * 1e-3
    lenslets = tuple(
        LensletSpec(center_um=c, aperture_diameter_um=diameter_um, focal_length_mm=focal_mm, shape=p.shape)
        for c in centres
    )
    dof_um = wavelength_um * p.immersion_index / na**2
    step_um = round(p.depth_step_dofs * dof_um, 4)
    start_um = -step_um * (p.depth_count - 1) / 2.0
    depth_spec = DepthSpec(
        depth_range_um=(start_um, start_um + step_um * (p.depth_count - 1)), depth_step_um=step_um
    )
    return Design(
        name="stress",
        kind="fourier",
        wavelength_nm=p.wavelength_nm,
        objective=ObjectiveSpec(
            magnification=p.magnification,
            numerical_aperture=na,
            immersion_index=p.immersion_index,
            tube_lens_focal_length_mm=200.0,
        ),
        relay=RelayLensSpec(focal_length_mm=relay_mm, field_stop_diameter_mm=stop_mm),
        mla=MLASpec(lenslets=lenslets),
        mla_to_camera_distance_mm=focal_mm,
        camera=CameraSpec(pixel_pitch_um=p.pixel_um, pixel_count=(p.pixels, p.pixels)),
        depths=depth_spec,
        accuracy=AccuracySpec(preset=p.accuracy),
    )


@st.composite
def design_parameters(draw: st.DrawFn, *, max_pixels: int = 256) -> DesignParameters:
    """Random :class:`DesignParameters` of a valid, fast-to-simulate Fourier design."""
    n = draw(st.sampled_from(IMMERSION))
    accuracy = draw(st.sampled_from(("preview", "standard")))
    return DesignParameters(
        wavelength_nm=draw(st.floats(400.0, 700.0)),
        immersion_index=n,
        numerical_aperture=n * draw(st.floats(0.1, 0.92)),
        magnification=draw(st.sampled_from(MAGNIFICATIONS)),
        pixels=draw(st.integers(64, max_pixels if accuracy == "preview" else min(max_pixels, 128))),
        pixel_um=draw(st.floats(2.0, 8.0)),
        layout=draw(st.sampled_from(LAYOUTS)),
        pitch_fraction=draw(st.floats(0.25, 0.6)),
        fill=draw(st.floats(0.3, 1.0)),
        shape=draw(st.sampled_from(("circle", "square"))),
        slack=draw(st.floats(0.0, 0.5)),
        focal_factor=draw(st.floats(1.01, 3.0)),
        depth_count=draw(st.integers(1, 3)),
        depth_step_dofs=draw(st.floats(0.5, 4.0)),
        accuracy=accuracy,
    )


designs = design_parameters().map(build_design)
"""Random valid designs (a strategy)."""
