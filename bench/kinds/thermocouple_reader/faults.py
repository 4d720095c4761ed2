"""What can go wrong with the thermocouple reader, made to happen to its simulator (bench/faults.py)."""

from bench.faults import device_fault

thermocouple_open = device_fault("open", channel=101)
