"""Scalar wave optics in torch: fields, propagation, lenses, MLA, objective, camera.

Each optical idea is a pure function ``Field -> Field``; SI units throughout.
"""
