"""The simulated PLC: the thermal twin served over the real protocols compd's drivers speak.

:mod:`compd.sim.plc.machine` runs the twin along a scenario and keeps the
truth (the thermal error, the offsets the PLC applied, the compensated error);
one server per driver instance of a compd config serves its signals and takes
its writes, over Modbus TCP, OPC UA, a Profibus gateway on CAN, or a serial
scanner on a pseudo-terminal. Every server follows :class:`~compd.sim.plc.server.PlcServer`.
"""
