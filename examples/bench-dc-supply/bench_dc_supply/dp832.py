"""The DP832's facts the driver, the config and the simulator share (Rigol DP800 Programming Guide;
README.md cites the pages)."""

RANGES = {1: (32.0, 3.2), 2: (32.0, 3.2), 3: (5.3, 3.2)}
"""Output -> (highest programmable voltage V, highest current A) (Programming Guide, :APPLy table:
CH1 and CH2 0-32 V / 0-3.2 A, CH3 0-5.3 V / 0-3.2 A)."""
DEFAULT_CURRENT_A = {1: 3.0, 2: 3.0, 3: 3.0}
"""The current limit after *RST (the :APPLy table's defaults)."""
VENDOR = "RIGOL TECHNOLOGIES"
MODEL = "DP832"
LAN_PORT = 5555
"""The DP800's raw SCPI socket on its LAN interface."""
