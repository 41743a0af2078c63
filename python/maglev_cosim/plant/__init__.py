"""Layer 1, the plant: the C plant's bindings (``fast``), its parameters and formulas, the
pure-Python reference, the linearisation, the model descriptions and calibrated copies of the FMU.
Imports only :mod:`maglev_cosim._resources`."""
