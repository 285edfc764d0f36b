"""compd: thermal-error compensation for CNC machine tools.

Predicts the thermal drift of a machine tool's tool centre point from cheap
signals (temperatures, spindle speed, spindle power) with transfer-function
models, and cancels it in real time.
"""

__version__ = "0.1.0"
