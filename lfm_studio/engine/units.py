"""SI unit constants, so code reads ``150 * um`` instead of ``150e-6``.

Everything inside the engine is in SI (metres, radians, seconds). Multiply by a
constant to enter SI, divide by it to leave: ``pitch_um = pitch / um``.
"""

m: float = 1.0
mm: float = 1e-3
um: float = 1e-6
nm: float = 1e-9
