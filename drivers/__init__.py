"""Protocol drivers (Modbus TCP/RTU, OPC UA, CAN gateway, serial), installed as ``compd.drivers``.

The folder is mapped to ``compd.drivers`` in pyproject.toml so that no
top-level ``drivers`` package lands in site-packages. The drivers and their
common interface arrive with the daemon and driver issues; until then this
package holds nothing, on purpose.
"""
