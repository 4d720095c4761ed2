"""What can go wrong with a chamber, made to happen to its simulators (bench/faults.py)."""

from bench.faults import device_fault, serial_fault

gauge_unplug = serial_fault("disconnect", "gauge")
modbus_timeout = device_fault("timeout")
modbus_busy = device_fault("exception", code=6)
modbus_disconnect = device_fault("disconnect")
chamber_runaway = device_fault("runaway", rate_c_per_min=lambda r: float(r.uniform(5.0, 20.0)))
control_sensor_open = device_fault("open_sensor", input=1)
