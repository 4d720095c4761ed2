"""What can go wrong with the supply, made to happen to its simulator (bench/faults.py)."""

from bench.faults import device_fault

supply_trip = device_fault("trip", output=1)
