"""Volume reconstruction from a light-field image: Richardson-Lucy (plain, accelerated, TV), Wiener, Tikhonov.

Every method takes a projector (``forward``/``adjoint``/``volume_shape``/``image_shape``;
Richardson-Lucy works with any, Wiener needs the shift-invariant one with cached OTFs,
Tikhonov that or the conventional lenslet-lattice one) and a camera image ``(Py, Px)`` in
photons with the camera's baseline removed, and runs in the projector's dtype and on its
device; the volume is then in photons per voxel (the unit of ``lfm-studio image --truth``).
Camera counts (ADU) are converted first with :func:`lfm_studio.engine.io.counts_to_photons`,
``max((ADU - baseline) / gain + c, 0) / QE``, whose second value (the noise floor ``c / QE``)
is the ``background`` to pass; the calibration comes from the image's metadata
(:func:`~lfm_studio.engine.io.resolve_calibration`) or the design's camera
(:func:`~lfm_studio.engine.io.camera_counts.design_camera`). An integer image (raw counts) is
warned about (:class:`~.guards.RawCountsWarning`).

Example::

    from lfm_studio.engine.io import counts_to_photons, resolve_calibration

    calibration, notes = resolve_calibration(metadata, counts)  # from the TIFF's camera metadata
    image, floor = counts_to_photons(counts, calibration, name="frame.tif")  # photons, baseline removed

    from lfm_studio.engine.reconstruct import accelerated_rl_options, richardson_lucy, richardson_lucy_iterates

    volume = richardson_lucy(setup.projector, image, background=floor, iterations=30)
    for it in richardson_lucy_iterates(setup.projector, image, acceleration="geometric",
                                       iterations=50, rtol=1e-3, progress=report, cancel=event):
        show(it.index, it.estimate, it.relative_change)

    fastest = accelerated_rl_options(setup.projector)            # geometric extrapolation, likelihood safeguard
    volume = richardson_lucy(setup.projector, image, iterations=10, **fastest)

    bp = wiener_butterworth_backprojector(setup.projector)      # Guo et al. 2020
    fast = richardson_lucy(setup.projector, image, backprojector=bp, iterations=3)
    stack = wiener(setup.projector, image, snr=100.0)           # per-depth Wiener (eq. 4.5): a preview,
                                                                 # every depth holds the image's light
    solution = tikhonov(setup.projector, image, mu=1e-3)        # per-frequency 3D Tikhonov

    volume = reconstruct_frame(setup.projector, image, method="rl-accelerated", background=floor)  # by name
    for method in methods():                                     # the registry every front end reads
        print(method.name, method.description, [o.name for o in method.options])
"""

from lfm_studio.engine.reconstruct.backprojectors import (
    FilteredBackProjector,
    wiener_butterworth_backprojector,
)
from lfm_studio.engine.reconstruct.builtin_methods import register_builtin
from lfm_studio.engine.reconstruct.dispatch import reconstruct_frame
from lfm_studio.engine.reconstruct.recommended import accelerated_rl_options
from lfm_studio.engine.reconstruct.registry import Method, Option, default_method, methods, register
from lfm_studio.engine.reconstruct.registry import get as get_method
from lfm_studio.engine.reconstruct.result_check import ReconstructionRejectedError, check_reconstruction
from lfm_studio.engine.reconstruct.richardson_lucy import (
    Iterate,
    RLOptions,
    poisson_nll,
    richardson_lucy,
    richardson_lucy_iterates,
)
from lfm_studio.engine.reconstruct.tikhonov import tikhonov
from lfm_studio.engine.reconstruct.wiener import wiener

__all__ = [
    "FilteredBackProjector",
    "Iterate",
    "Method",
    "Option",
    "RLOptions",
    "ReconstructionRejectedError",
    "accelerated_rl_options",
    "check_reconstruction",
    "default_method",
    "get_method",
    "methods",
    "poisson_nll",
    "reconstruct_frame",
    "register",
    "register_builtin",
    "richardson_lucy",
    "richardson_lucy_iterates",
    "tikhonov",
    "wiener",
    "wiener_butterworth_backprojector",
]
