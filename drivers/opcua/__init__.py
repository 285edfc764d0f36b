"""OPC UA (config ``type: opcua``), one module per concern.

``driver`` (the driver class, asyncua), ``settings`` (its config),
``security`` (certificates, the password, refusals explained) and
``values`` (variants to and from floats). This file imports none of them.
"""
