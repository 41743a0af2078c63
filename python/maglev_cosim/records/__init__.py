"""Layer 4, records: the CE152 record format, the readers of real rigs' records, the emulators
(``emulator``, the model's own; ``emulator_ivp``, written independently from the paper) and synth.
Imports the loop and the layers below."""
