"""Layer 3, the closed loop: the PID and the other controllers, the loop simulated (fast path,
FMU or reference), the FMU runner, the loop as one container FMU, the paper's controller design.
Imports the plant and the rigs."""
