"""Force/torque sensor-actuator drivers (TR §4.6.2): two vendors, one `f_m`."""
