"""Layer 6, reports: what the diagnosis found, written (``diagnosis.json``, ``report.md``, the
HTML page, the calibrated FMU), and the benchmark. Imports every layer below."""
