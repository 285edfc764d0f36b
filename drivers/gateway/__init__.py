"""Profibus DP through a gateway (config ``type: profibus_gateway``), one module per concern.

``driver`` (the driver class), ``settings`` (its config), ``image`` (the DP
process image and its address grammar), ``status`` (the gateway's status
byte), and the two transports: ``modbus`` (Modbus TCP) and ``can`` (CAN).
This file imports none of them, so a settings check loads no bus library.
"""
