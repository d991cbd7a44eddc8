"""Forward models: turn an optical system into a PSF stack and a projector.

One object per system kind (:mod:`.kinds`: :data:`~.kinds.FOURIER`, :data:`~.kinds.CONVENTIONAL`,
found with :func:`~.kinds.kind_of`) owns its PSF computation, its projector and its cache policy:

- Fourier LFM (:mod:`.kinds_fourier`): MLA on the Fourier (pupil-conjugate) plane, laterally
  shift-invariant; :mod:`.fourier_system`, :mod:`.fourier_psf`.
- conventional LFM (:mod:`.kinds_conventional`): MLA on the native image plane, lenslet
  patterns on a lattice; :mod:`.conventional_system`, :mod:`.conventional_psf`.
"""
