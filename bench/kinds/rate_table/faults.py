"""What can go wrong with the rate table, made to happen to its simulator (bench/faults.py)."""

from bench.faults import device_fault

can_error_frames = device_fault("error_frames", count=lambda r: int(r.integers(5, 51)))
can_bus_off = device_fault("silent")
table_stuck = device_fault("stuck")
