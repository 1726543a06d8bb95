"""Real hardware: the sensor camera (camera.py); the printer host lives beside it."""
