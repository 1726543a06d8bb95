"""Real hardware: the Marlin printer host, its motion-time model and printer profiles."""
