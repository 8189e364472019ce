"""Readers that turn PX4 ULog and ArduPilot DataFlash files and sun-device CSV logs into one canonical
:class:`~ingest.flightlog.FlightLog`; :func:`ingest.log_formats.load_flight_log` reads a flight log of any format.

Import from the module that defines a name: this file imports nothing, so importing one ``ingest`` module runs no
other (and no reader imports another through it).
"""
