"""Shared test settings: our own warnings are errors unless a test expects them."""
