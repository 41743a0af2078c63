"""maglev-cosim: the Humusoft CE152 magnetic levitation rig as an FMI 2.0 co-simulation FMU.

Units follow the paper: positions in m, velocities in m/s, currents in A, voltages in V,
converter values in machine units (MU, ±1 full range), times in s.

:func:`fmu_path` is the installed plant FMU (or ``$MAGLEV_FMU`` when set).
"""

from ._resources import fmu_path

__version__ = "0.1.0"

__all__ = ["fmu_path", "__version__"]
