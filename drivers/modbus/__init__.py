"""Modbus TCP and RTU (config ``type: modbus``), one module per concern.

``driver`` (the driver class, pymodbus), ``settings`` (its config) and
``addresses`` (the address grammar, parsed without pymodbus). This file
imports none of them.
"""
