"""The 6-DOF trackball (TR §4.6.2, Figure 10): a sensor-actuator driver played by a script or by the operator."""
