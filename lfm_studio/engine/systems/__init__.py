"""Forward models: turn an optical system into a PSF stack.

``fourier`` — MLA on the Fourier (pupil-conjugate) plane, laterally shift-invariant.
"""
