"""Real hardware: the Marlin printer host and its motion-time model (printer.py, motion.py, gcode.py)
and the sensor camera (camera.py)."""
