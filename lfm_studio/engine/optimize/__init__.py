"""Optimisation of light-field microscope designs (thesis chapter 5)."""
