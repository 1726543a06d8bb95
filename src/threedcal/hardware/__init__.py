"""Real hardware: the Marlin printer host and its motion-time model (printer.py, motion.py, gcode.py),
the sensor camera (camera.py) and the ReSkin board's serial reader (reskin.py)."""
